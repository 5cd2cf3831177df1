// vdb2nvdb's exit codes, and the error that carries a message and one of
// them up to main() (tools/vdb2nvdb/main.cpp; the .vdb reader,
// src/loader/vdb_read.cpp, catches it too).
#pragma once

#include <stdexcept>
#include <string>

namespace vdb2nvdb {

/// Exit codes of the CLI.
enum Exit : int { ExitOk = 0, ExitError = 1, ExitUsage = 2, ExitVerify = 3 };

/// An error with a message for the user and an exit code.
struct Error : std::runtime_error {
    int code;
    explicit Error(const std::string &msg, int code = ExitError)
        : std::runtime_error(msg), code(code) {}
};

} // namespace vdb2nvdb
