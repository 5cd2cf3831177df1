// src/loader/vdb_reader_protocol.h -- what nanovdb-vdb-reader (the child,
// vdb_reader_main.cpp) is asked, and what it sends its parent
// (vdb_import.cpp) on file descriptor 3: one Reply, then its name, message
// and payload.
//
// The requests (its command line):
//   nanovdb-vdb-reader FILE.vdb SELECTOR [--keep-level-sets]
//       one grid, converted; a level set made a fog volume unless
//       --keep-level-sets. Payload: the NanoVDB grid.
//   nanovdb-vdb-reader --fog-nvdb FILE.nvdb INDEX
//       grid INDEX of a NanoVDB file, a level set, made a fog volume as
//       vdb2nvdb makes it (nanovdbvolume's level_set="fog" for .nvdb files:
//       the conversion needs OpenVDB, which the plugin does not link).
//       Payload: the NanoVDB grid.
//   nanovdb-vdb-reader --list FILE.vdb
//       every grid's name, type and class, no voxels read. Payload:
//       `entries` records, each a ListEntry, then its name and type.
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
    uint64_t grid_bytes; ///< the payload that follows (Ok only): the NanoVDB grid,
                         ///< or a listing's records
    uint32_t entries;    ///< a listing: how many ListEntry records the payload holds
    uint32_t reserved;
};

/// One grid of a listing (--list), followed by its name and type bytes
struct ListEntry {
    uint32_t grid_class;            ///< OpenVDB's GridClass (0 unknown, 1 level set, ...)
    uint32_t name_bytes, type_bytes; ///< each at most kMaxText
    uint32_t reserved;
};

constexpr uint32_t kMaxText = 1u << 16;

} // namespace nanovdb_loader::vdb_reader
