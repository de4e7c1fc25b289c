#pragma once

// Helpers for tests that run the project's programs and scripts: scratch folders, running a
// command with its output captured, and where the sources and programs are.

#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <system_error>

namespace raillomer::test {

/// The exit code and captured output of a command.
struct CommandResult {
  int exit_code = -1;  ///< -1 if the command did not exit normally
  std::string out;
  std::string err;
};

/// The whole content of a file ("" if it cannot be read).
inline std::string ReadText(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

/// Quotes text for the shell (single quotes).
inline std::string ShellQuote(const std::string& text) {
  std::string quoted = "'";
  for (char c : text) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return quoted + "'";
}

/// Runs a shell command; stdout and stderr are captured through files in `scratch_dir`.
inline CommandResult RunCommand(const std::string& command,
                                const std::filesystem::path& scratch_dir) {
  const std::filesystem::path out = scratch_dir / "stdout.txt", err = scratch_dir / "stderr.txt";
  const int status = std::system(
      (command + " >" + ShellQuote(out.string()) + " 2>" + ShellQuote(err.string())).c_str());
  CommandResult result;
  result.exit_code = status != -1 && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  result.out = ReadText(out);
  result.err = ReadText(err);
  return result;
}

/// The repository root: $RAILLOMER_SOURCE, else the one this test was built from.
inline std::filesystem::path SourceDir() {
  const char* value = std::getenv("RAILLOMER_SOURCE");
  return value ? value : RAILLOMER_SOURCE_DIR;
}

/// The folder of the programs: $RAILLOMER_BIN (set by ctest), else the build's bin folder.
inline std::filesystem::path BinDir() {
  const char* value = std::getenv("RAILLOMER_BIN");
  return value ? value : RAILLOMER_BIN_DIR;
}

/// A program run in the background through the shell (`exec`, so the pid is the program's),
/// for tests that signal it part way.
class ChildProcess {
 public:
  explicit ChildProcess(const std::string& command) {
    pid_ = fork();
    if (pid_ == 0) {
      const std::string exec = "exec " + command;
      execl("/bin/sh", "sh", "-c", exec.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
  }
  ~ChildProcess() {
    if (pid_ > 0) Signal(SIGKILL);
  }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  /// True while the program runs (false once it ended or was waited for).
  bool Running() {
    if (pid_ <= 0) return false;
    if (waitpid(pid_, &status_, WNOHANG) == pid_) pid_ = -1;
    return pid_ > 0;
  }
  /// Sends a signal and waits for the program to end.
  void Signal(int signal) {
    if (pid_ <= 0) return;
    kill(pid_, signal);
    Wait();
  }
  /// Waits for the program to end; its exit code (-1 if a signal ended it).
  int Wait() {
    if (pid_ > 0) {
      waitpid(pid_, &status_, 0);
      pid_ = -1;
    }
    return WIFEXITED(status_) ? WEXITSTATUS(status_) : -1;
  }
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int status_ = 0;
};

/// A fresh folder under the system's temporary folder, removed with everything in it.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& prefix) {
    std::string pattern = (std::filesystem::temp_directory_path() / (prefix + "XXXXXX")).string();
    if (::mkdtemp(pattern.data()) != nullptr) path_ = pattern;
  }
  ~ScratchDir() {
    std::error_code ignored;
    if (!path_.empty()) std::filesystem::remove_all(path_, ignored);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  /// Empty if the folder could not be made.
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

}  // namespace raillomer::test
