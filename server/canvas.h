#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace raillomer::server {

using Rgb = std::array<uint8_t, 3>;

/// An RGB raster for the server's pictures (change snapshots): dots, lines, rectangles and
/// text in a 5x7 pixel font (upper case, digits and a little punctuation), encoded as PNG.
class Canvas {
 public:
  Canvas(int width, int height, Rgb background);
  int width() const { return width_; }
  int height() const { return height_; }

  void Dot(int x, int y, int radius, Rgb colour);
  void Line(int x0, int y0, int x1, int y1, Rgb colour, int dash = 0);
  void Rect(int x0, int y0, int x1, int y1, Rgb colour);
  void Fill(int x0, int y0, int x1, int y1, Rgb colour);
  /// Text with its top left at (x, y), `scale` pixels per font pixel; lower case is drawn as
  /// upper case, characters the font lacks as blanks.
  void Text(int x, int y, const std::string& text, Rgb colour, int scale = 1);
  static int TextWidth(const std::string& text, int scale = 1) {
    return static_cast<int>(text.size()) * 6 * scale;
  }

  /// The picture as PNG bytes (8-bit RGB, zlib-compressed).
  std::string Png() const;

 private:
  void Set(int x, int y, Rgb colour);

  int width_, height_;
  std::vector<uint8_t> rgb_;
};

}  // namespace raillomer::server
