// src/loader/vdb_reader_budget.h -- the memory a .vdb may make its reader
// allocate, and how that is enforced.
//
// A .vdb declares sizes (grid counts, node counts, metadata lengths,
// compressed chunk sizes) that OpenVDB allocates as read. A damaged file
// declares garbage: 75 KB files were seen to drive a load to 10 GB. An
// intact file cannot need more than its own bytes inflate to: at worst a
// leaf of constant values costs ~125 bytes on disk (value mask, a byte of
// metadata, a compressed chunk) and ~2.2 KB as an OpenVDB leaf, plus
// ~2.1 KB as a NanoVDB leaf while both are alive, and a level set is
// copied once to become a fog volume: about 70x. So the budget is
//     kBaseBytes + kBytesPerFileByte x (file size)
// of C++ heap (every `new` of OpenVDB's reader and of the conversion goes
// through the budget: vdb_reader_budget.cpp replaces operator new in the
// reader process and the fuzzer), and the kernel's RLIMIT_DATA caps
// everything else (malloc, TBB's threads) at the budget plus kSlackBytes.
// A request past the budget throws std::bad_alloc BEFORE it allocates.
// NVDB_VDB_READER_MEMORY_MB sets the budget in MiB instead.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

namespace nanovdb_loader::vdb_reader {

constexpr uint64_t kBaseBytes = uint64_t(64) << 20;
constexpr uint64_t kBytesPerFileByte = 96;
constexpr uint64_t kSlackBytes = uint64_t(128) << 20;

/// The budget for a file of `file_bytes` (NVDB_VDB_READER_MEMORY_MB
/// overrides it). Inline: the plugin's side (vdb_import.cpp) caps the
/// reply with it, without the operator new of vdb_reader_budget.cpp.
inline uint64_t memory_budget(uint64_t file_bytes) {
    if (const char *mb = std::getenv("NVDB_VDB_READER_MEMORY_MB")) {
        char *end = nullptr;
        unsigned long long v = std::strtoull(mb, &end, 10);
        if (end != mb && *end == '\0' && v > 0 && v < (1ull << 44))
            return uint64_t(v) << 20;
    }
    // (saturating: a file of petabytes is not a reason to wrap around)
    if (file_bytes > (UINT64_MAX - kBaseBytes) / kBytesPerFileByte)
        return UINT64_MAX;
    return kBaseBytes + kBytesPerFileByte * file_bytes;
}

/// A size for a message: MiB from 1 MiB up, KiB below (a block under 1 MiB
/// that crosses the budget is not "0 MiB"), bytes below 1 KiB
inline std::string budget_size(uint64_t bytes) {
    if (bytes >= (uint64_t(1) << 20))
        return std::to_string(bytes >> 20) + " MiB";
    if (bytes >= 1024)
        return std::to_string(bytes >> 10) + " KiB";
    return std::to_string(bytes) + " bytes";
}

/// The error for a read that asked for more than `budget`: `label` (the
/// quoted file name), the largest block refused, the budget and its knob
inline std::string budget_refusal(const std::string &label, uint64_t budget,
                                  uint64_t refused_block) {
    return label + ": damaged: reading it asks for more memory than a file of its size can "
           "need (" + (refused_block ? "a block of " + budget_size(refused_block) + "; "
                                     : std::string()) +
           "the budget is " + budget_size(budget) + ", NVDB_VDB_READER_MEMORY_MB raises it)";
}

/// Enforces `bytes` as the budget of live operator-new bytes from now on
/// (the default is no limit)
void set_heap_budget(uint64_t bytes);

/// The budget for a scope (vdb2nvdb's reading), the previous one after
struct ScopedHeapBudget {
    explicit ScopedHeapBudget(uint64_t bytes);
    ~ScopedHeapBudget();
    ScopedHeapBudget(const ScopedHeapBudget &) = delete;
    ScopedHeapBudget &operator=(const ScopedHeapBudget &) = delete;
    uint64_t previous;
};

/// Live operator-new bytes, and their peak since set_heap_budget()
uint64_t heap_live_bytes();
uint64_t heap_peak_bytes();
/// The largest single request refused (0: none)
uint64_t heap_refused_bytes();

} // namespace nanovdb_loader::vdb_reader
