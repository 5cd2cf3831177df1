// libFuzzer harness over the .vdb path: the steps nanovdb-vdb-reader runs
// (src/loader/vdb_read.cpp: OpenVDB's header, grid descriptors and the
// chosen grid, then vdb2nvdb's preparation and OpenToNanoVDB), under the
// reader's memory budget (src/loader/vdb_reader_budget.cpp replaces
// operator new here as in the reader), then the plugin's side: the
// converted bytes through the .nvdb validation (nanovdb_loader::
// validate_grid) and value policy, as nanovdbvolume checks them.
//
// One input = the bytes of a .vdb file, written to a memfd and read through
// its /proc/self/fd path. The grid is chosen as the plugin chooses ("": the
// first float or vec3s grid), and, from one input byte, by index.
// Oracles, besides ASan/UBSan:
//  * nanovdb_loader::Error is the only exception allowed out of the reader;
//  * a budget refusal (std::bad_alloc) is allowed and must say so;
//  * a grid the reader converts must validate as a .nvdb grid: our own
//    conversion never writes a grid the plugin would refuse, and its size
//    is the size it reports.
// Findings inside OpenVDB's own reading (libopenvdb.so, which trusts its
// stream) are what the reader's process contains: the plugin never runs
// this code in its own process (src/loader/vdb_import.cpp).
//
// Build: cmake -DNVDB_BUILD_FUZZ=ON with clang (tests/fuzz/CMakeLists.txt).
// Run:   fuzz_vdb CORPUS_DIR [SEED_DIRS...] -max_total_time=30

#include "../../src/loader/vdb_read.h"
#include "../../src/loader/vdb_reader_budget.h"

#include <nanovdb_loader/load.h>

#include "mem_file.h"

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <string>
#include <vector>

namespace nio = nanovdb_loader;
namespace rd = nanovdb_loader::vdb_reader;

namespace {

[[noreturn]] void die(const char *what, const char *detail = "") {
    std::fprintf(stderr, "fuzz_vdb: %s %s\n", what, detail);
    std::abort();
}

using nvdb_fuzz::MemFile; // (mem_file.h)

void read_one(const std::string &path, size_t size, const std::string &selector) {
    nio::VdbGrid grid;
    {
        rd::ScopedHeapBudget budget(rd::memory_budget(size));
        try {
            grid = nio::read_vdb_grid(path, selector);
        } catch (const nio::Error &) {
            return; // the clear error the plugin reports
        } catch (const std::bad_alloc &) {
            if (!rd::heap_refused_bytes())
                die("std::bad_alloc without a budget refusal");
            return;
        }
    }
    if (!grid.data || grid.size == 0)
        die("a converted grid without bytes");
    // The plugin's side: the bytes validate as any .nvdb grid
    std::vector<uint32_t> words((grid.size + 3) / 4);
    std::memcpy(words.data(), grid.data.get(), grid.size);
    try {
        nio::ValidatedGrid v = nio::validate_grid("\"" + path + "\"", words.data(), grid.size);
        (void) nio::scan_values(v);
    } catch (const nio::Error &e) {
        die("our conversion wrote a grid the validation refuses:", e.what());
    }
}

} // namespace

// OpenVDB leaks what it had built when a damaged file makes it throw (a
// root child replaced in its table, nodes of an unfinished read). The
// reader process exits after one file, so nothing accumulates there; here
// those leaks are not findings.
extern "C" const char *__asan_default_options() { return "detect_leaks=0"; }

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    MemFile file(data, size);
    read_one(file.path, size, "");
    // A second grid by index, chosen by the input's last byte (files hold
    // several: density, heat, velocity)
    if (size > 0 && (data[size - 1] & 3) != 0)
        read_one(file.path, size, std::to_string(data[size - 1] & 3));
    return 0;
}
