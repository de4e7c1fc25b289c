// The HTTP front's own parsing, on known answers: percent-decoding, query strings, byte
// ranges, strict numbers and cookies; and the web root's path resolution on a real folder
// with symlinks.
#include <unistd.h>

#include <fstream>

#include <gtest/gtest.h>

#include "server/http_parse.h"
#include "server/static_files.h"
#include "tests/support/process.h"

namespace raillomer::server {
namespace {

TEST(HttpParse, PercentDecodingRefusesMalformedEscapesAndNul) {
  std::string out;
  EXPECT_TRUE(PercentDecode("/lines/Test%20line", false, &out));
  EXPECT_EQ(out, "/lines/Test line");
  EXPECT_TRUE(PercentDecode("..%2Fx%2fy", false, &out));
  EXPECT_EQ(out, "../x/y");
  EXPECT_TRUE(PercentDecode("a+b", true, &out));
  EXPECT_EQ(out, "a b");
  EXPECT_TRUE(PercentDecode("a+b", false, &out));
  EXPECT_EQ(out, "a+b");
  for (const char* bad : {"%", "%2", "%zz", "%0g", "/index.html%00.txt"})
    EXPECT_FALSE(PercentDecode(bad, false, &out)) << bad;
}

TEST(HttpParse, QueryStrings) {
  std::vector<std::pair<std::string, std::string>> params;
  std::string error;
  ASSERT_TRUE(ParseQuery("level=2&bbox=1%2C2,3,4&&flag&line=K+12", &params, &error));
  ASSERT_EQ(params.size(), 4u);
  EXPECT_EQ(params[0], std::make_pair(std::string("level"), std::string("2")));
  EXPECT_EQ(params[1].second, "1,2,3,4");
  EXPECT_EQ(params[2], std::make_pair(std::string("flag"), std::string()));
  EXPECT_EQ(params[3].second, "K 12");
  EXPECT_FALSE(ParseQuery("a=%00", &params, &error));
  EXPECT_EQ(error, "the query string has a malformed %-escape or a NUL byte");
  // Which of two values to take would be a guess: refused, whichever comes first.
  EXPECT_FALSE(ParseQuery("kind=added&level=2&kind=bogus", &params, &error));
  EXPECT_EQ(error, "the query string names 'kind' twice");
}

TEST(HttpParse, OneRangeIsServedAndNoRangeAsksForMoreThanTheEntity) {
  ByteRange r;
  ASSERT_EQ(ParseRange("bytes=10-19", 100, &r), RangeAnswer::kPart);
  EXPECT_EQ(r.first, 10u);
  EXPECT_EQ(r.last, 19u);
  ASSERT_EQ(ParseRange("bytes=90-", 100, &r), RangeAnswer::kPart);
  EXPECT_EQ(r.last, 99u);
  ASSERT_EQ(ParseRange("bytes=95-500", 100, &r), RangeAnswer::kPart);
  EXPECT_EQ(r.last, 99u);
  ASSERT_EQ(ParseRange("bytes=-5", 100, &r), RangeAnswer::kPart);
  EXPECT_EQ(r.first, 95u);
  ASSERT_EQ(ParseRange("bytes=-500", 100, &r), RangeAnswer::kPart);
  EXPECT_EQ(r.first, 0u);
  EXPECT_EQ(ParseRange("bytes=100-", 100, &r), RangeAnswer::kUnsatisfiable);
  EXPECT_EQ(ParseRange("bytes=-0", 100, &r), RangeAnswer::kUnsatisfiable);
  // Several ranges, other units and malformed headers: the whole entity.
  for (const char* whole : {"bytes=0-0,2-2",
                            "items=0-5",
                            "bytes=5-2",
                            "bytes=x-",
                            "bytes=1-2-3",
                            "",
                            "bytes=18446744073709551616-"})
    EXPECT_EQ(ParseRange(whole, 100, &r), RangeAnswer::kWhole) << whole;
}

TEST(HttpParse, StrictNumbers) {
  int64_t v = 0;
  EXPECT_TRUE(ParseInt64("12", 0, 100, &v));
  EXPECT_EQ(v, 12);
  EXPECT_TRUE(ParseInt64("-7", -10, 10, &v));
  for (const char* bad : {"1e3", "1.0", "", " 1", "1 ", "+1", "0x10", "101", "9223372036854775808"})
    EXPECT_FALSE(ParseInt64(bad, -1000, 100, &v)) << bad;
  double d = 0.0;
  EXPECT_TRUE(ParseFiniteDouble("12.345", &d));
  EXPECT_DOUBLE_EQ(d, 12.345);
  EXPECT_TRUE(ParseFiniteDouble("1e3", &d));
  EXPECT_DOUBLE_EQ(d, 1000.0);
  for (const char* bad : {"", "abc", "1,2", " 1", "1x", "inf", "nan", "1e999", "0x1p3"})
    EXPECT_FALSE(ParseFiniteDouble(bad, &d)) << bad;
}

TEST(HttpParse, AnIfNoneMatchListOrStarMatchesAnETag) {
  EXPECT_TRUE(EtagMatches("\"a1\"", "\"a1\""));
  EXPECT_TRUE(EtagMatches("\"x\", W/\"a1\" ,\"y\"", "\"a1\""));
  EXPECT_TRUE(EtagMatches("*", "\"a1\""));
  EXPECT_FALSE(EtagMatches("\"a12\", \"a\"", "\"a1\""));
  EXPECT_FALSE(EtagMatches("", "\"a1\""));
}

TEST(HttpParse, Cookies) {
  EXPECT_EQ(CookieValue("a=1; raillomer_token=abc; b=2", "raillomer_token"), "abc");
  EXPECT_EQ(CookieValue("raillomer_token_x=1", "raillomer_token"), "");
  EXPECT_TRUE(EqualsIgnoreCase("Content-Length", "content-length"));
  EXPECT_FALSE(EqualsIgnoreCase("Content-Length", "content-lengt"));
}

TEST(HttpParse, PathPatternsMatchSegmentBySegment) {
  const PathPattern tile("/api/v1/runs/{run}/tiles/{level}/{ix}/{iy}");
  std::vector<std::string_view> captures;
  ASSERT_TRUE(tile.Match("/api/v1/runs/3/tiles/0/-12/40", &captures));
  EXPECT_EQ(captures, (std::vector<std::string_view>{"3", "0", "-12", "40"}));
  for (const char* other : {"/api/v1/runs/3/tiles/0/-12",
                            "/api/v1/runs/3/tiles/0/-12/40/",
                            "/api/v1/runs//tiles/0/1/2",
                            "/api/v1/runs/3/tile/0/1/2",
                            "",
                            "api"})
    EXPECT_FALSE(tile.Match(other, &captures)) << other;
  const PathPattern line("/api/v1/lines/{line}");
  ASSERT_TRUE(line.Match("/api/v1/lines/..%2Fx%2Fy", &captures));
  EXPECT_EQ(captures[0], "..%2Fx%2Fy");
  EXPECT_TRUE(PathPattern("/health").Match("/health", nullptr));
  EXPECT_FALSE(PathPattern("/health").Match("/health/x", nullptr));
}

TEST(StaticFiles, ResolvesInsideTheRootOnly) {
  test::ScratchDir dir("raillomer_static_");
  const auto web = dir.path() / "web";
  std::filesystem::create_directories(web / "assets");
  std::ofstream(web / "index.html") << "viewer";
  std::ofstream(web / "assets" / "app.js") << "js";
  std::ofstream(dir.path() / "secret.txt") << "secret";
  std::filesystem::create_symlink(dir.path() / "secret.txt", web / "leak.txt");
  std::filesystem::create_symlink(dir.path(), web / "up");
  std::filesystem::create_symlink("index.html", web / "home.html");
  const StaticFiles files(web.string());
  StaticFiles::File f;
  ASSERT_TRUE(files.Resolve("/", &f));
  EXPECT_EQ(f.path, std::filesystem::canonical(web / "index.html").string());
  EXPECT_EQ(f.content_type, "text/html; charset=utf-8");
  EXPECT_EQ(f.size, 6u);
  ASSERT_TRUE(files.Resolve("/assets/app.js", &f));
  EXPECT_EQ(f.content_type, "text/javascript; charset=utf-8");
  EXPECT_TRUE(files.Resolve("/home.html", &f));
  for (const char* outside : {"/leak.txt",
                              "/up/secret.txt",
                              "/../secret.txt",
                              "/assets/../../secret.txt",
                              "/assets//app.js",
                              "/./index.html",
                              "/nothing",
                              "/assets\\app.js",
                              "relative.html",
                              "/assets"})
    EXPECT_FALSE(files.Resolve(outside, &f)) << outside;
  EXPECT_FALSE(StaticFiles("").enabled());
}

}  // namespace
}  // namespace raillomer::server
