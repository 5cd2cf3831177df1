// src/loader/vdb_reader_protocol.h -- what nanovdb-vdb-reader (the child,
// vdb_reader_main.cpp) sends its parent (vdb_import.cpp) on file
// descriptor 3: one Reply, then its name, message and grid bytes.
//
// The parent trusts none of it: every length is checked against the
// budget before it is read, and the grid bytes are validated as any .nvdb
// grid is (nanovdb_loader::validate_grid) before a lookup touches them.
#pragma once

#include <cstdint>

namespace nanovdb_loader::vdb_reader {

/// The descriptor the child writes its reply to
constexpr int kReplyFd = 3;

constexpr char kMagic[8] = { 'N', 'V', 'D', 'B', 'R', 'D', 'R', '1' };

/// The exit code of a child that ran out of its memory budget (it has
/// written an error reply too, where it could)
constexpr int kExitOutOfBudget = 3;

enum class Status : uint32_t { Ok = 0, Error = 1, OutOfBudget = 2 };

struct Reply {
    char magic[8];
    Status status;
    uint32_t index, source_class, fogged;
    uint32_t name_bytes, message_bytes; ///< each at most kMaxText
    double read_seconds, convert_seconds;
    uint64_t peak_bytes; ///< the reader's peak resident memory (VmHWM)
    uint64_t grid_bytes; ///< the NanoVDB grid that follows (Ok only)
};

constexpr uint32_t kMaxText = 1u << 16;

} // namespace nanovdb_loader::vdb_reader
