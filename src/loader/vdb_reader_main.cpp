// nanovdb-vdb-reader: reads one grid of a .vdb file and converts it to
// NanoVDB, lists a .vdb file's grids, or makes a .nvdb level set a fog
// volume, in a process of its own, for nanovdbvolume and nanovdb_mitsuba's
// grid listing (nanovdb_loader::import_vdb_grid and list_vdb_grids,
// vdb_import.cpp, start it).
//
//   nanovdb-vdb-reader FILE.vdb SELECTOR [--keep-level-sets]
//   nanovdb-vdb-reader --fog-nvdb FILE.nvdb INDEX
//   nanovdb-vdb-reader --list FILE.vdb   (the reply goes to descriptor 3;
//                                         vdb_reader_protocol.h)
//
// OpenVDB's reader trusts its stream; a damaged file can corrupt the heap
// of the process that reads it. Here that process is this one, and all it
// holds is the file. It runs under a memory budget
// (vdb_reader_budget.h): operator new refuses past it, RLIMIT_DATA caps
// the rest. Its reply is vdb_reader_protocol.h's.

#include "vdb_read.h"
#include "vdb_reader_budget.h"
#include "vdb_reader_protocol.h"

#include <tbb/global_control.h>

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdlib>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <new>
#include <string>
#include <thread>
#include <vector>

namespace nl = nanovdb_loader;
namespace rd = nanovdb_loader::vdb_reader;

namespace {

bool write_all(int fd, const void *data, size_t size) {
    const char *p = static_cast<const char *>(data);
    while (size > 0) {
        ssize_t n = ::write(fd, p, size);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return false;
        p += n;
        size -= size_t(n);
    }
    return true;
}

/// This process's peak resident memory since exec (VmHWM: getrusage's
/// ru_maxrss would count the parent's pages, which posix_spawn shares
/// until exec)
uint64_t peak_bytes() {
    FILE *f = std::fopen("/proc/self/status", "r");
    if (!f)
        return 0;
    char line[256];
    unsigned long long kb = 0;
    while (std::fgets(line, sizeof line, f))
        if (std::sscanf(line, "VmHWM: %llu kB", &kb) == 1)
            break;
    std::fclose(f);
    return uint64_t(kb) * 1024;
}

/// The request being answered: "grid", "list" or "fog-nvdb"
const char *g_request = "grid";

/// NVDB_VDB_READER_REPORT=FILE: one JSON line per read appended to FILE
/// (the file, the request, status, peak, seconds): what a farm or a test
/// measures
void report(const std::string &path, rd::Status status, uint64_t peak, double seconds) {
    const char *to = std::getenv("NVDB_VDB_READER_REPORT");
    if (!to || !*to)
        return;
    if (FILE *f = std::fopen(to, "a")) {
        std::string escaped;
        for (char c : path)
            escaped += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
        std::fprintf(f, "{\"file\": \"%s\", \"request\": \"%s\", \"status\": %u, "
                        "\"peak_mb\": %.2f, \"seconds\": %.4f}\n", escaped.c_str(),
                     g_request, unsigned(status), double(peak) / (1 << 20), seconds);
        std::fclose(f);
    }
}

std::string g_path;
std::chrono::steady_clock::time_point g_t0;

int reply(rd::Status status, const nl::VdbGrid *grid, std::string message,
          const std::vector<nl::VdbGridInfo> *listing = nullptr) {
    rd::Reply r{};
    r.peak_bytes = peak_bytes();
    report(g_path, status, r.peak_bytes,
           std::chrono::duration<double>(std::chrono::steady_clock::now() - g_t0).count());
    std::memcpy(r.magic, rd::kMagic, sizeof r.magic);
    r.status = status;
    message.resize(std::min<size_t>(message.size(), rd::kMaxText));
    std::string name;
    if (grid) {
        name = grid->name.substr(0, rd::kMaxText);
        r.index = grid->index;
        r.source_class = grid->source_class;
        r.fogged = grid->fogged;
        r.read_seconds = grid->read_seconds;
        r.convert_seconds = grid->convert_seconds;
        r.grid_bytes = grid->size;
    }
    // A listing: one ListEntry, its name and its type per grid
    std::string records;
    if (listing) {
        for (const nl::VdbGridInfo &g : *listing) {
            rd::ListEntry e{};
            const std::string gname = g.name.substr(0, rd::kMaxText);
            const std::string gtype = g.type.substr(0, rd::kMaxText);
            e.grid_class = g.grid_class;
            e.name_bytes = uint32_t(gname.size());
            e.type_bytes = uint32_t(gtype.size());
            records.append(reinterpret_cast<const char *>(&e), sizeof e);
            records += gname + gtype;
        }
        r.entries = uint32_t(listing->size());
        r.grid_bytes = records.size();
    }
    r.name_bytes = uint32_t(name.size());
    r.message_bytes = uint32_t(message.size());
    bool ok = write_all(rd::kReplyFd, &r, sizeof r) &&
              write_all(rd::kReplyFd, name.data(), name.size()) &&
              write_all(rd::kReplyFd, message.data(), message.size()) &&
              (!grid || write_all(rd::kReplyFd, grid->data.get(), grid->size)) &&
              write_all(rd::kReplyFd, records.data(), records.size());
    if (!ok)
        return 1;
    return status == rd::Status::OutOfBudget ? rd::kExitOutOfBudget
                                              : (grid || listing ? 0 : 1);
}


} // namespace

int main(int argc, char **argv) {
    const std::vector<std::string> args(argv + 1, argv + argc);
    const bool list = args.size() == 2 && args[0] == "--list";
    const bool fog_nvdb = args.size() == 3 && args[0] == "--fog-nvdb";
    const bool keep = args.size() == 3 && args[2] == "--keep-level-sets";
    if (!list && !fog_nvdb && !keep && (args.size() != 2 || args[0].rfind("--", 0) == 0)) {
        std::fprintf(stderr, "usage: nanovdb-vdb-reader FILE.vdb SELECTOR [--keep-level-sets] | "
                             "--fog-nvdb FILE.nvdb INDEX | --list FILE.vdb (reply on fd 3; "
                             "started by nanovdbvolume; vdb_reader_protocol.h)\n");
        return 2;
    }
    g_t0 = std::chrono::steady_clock::now();
    const std::string path = list || fog_nvdb ? args[1] : args[0];
    const std::string selector = list ? "" : fog_nvdb ? args[2] : args[1];
    g_path = path;
    g_request = list ? "list" : fog_nvdb ? "fog-nvdb" : "grid";
    std::error_code ec;
    const uint64_t file_bytes = std::filesystem::file_size(path, ec);
    const uint64_t budget = rd::memory_budget(ec ? 0 : file_bytes);
    // Everything else this process maps writable (malloc outside operator
    // new, TBB's thread stacks) under the kernel's cap
    if (budget < UINT64_MAX - rd::kSlackBytes) {
        rlimit lim{ rlim_t(budget + rd::kSlackBytes), rlim_t(budget + rd::kSlackBytes) };
        setrlimit(RLIMIT_DATA, &lim);
    }
    // A thread stack each: at most 8 threads, whatever the machine
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                std::clamp(std::thread::hardware_concurrency(), 1u, 8u));
    rd::set_heap_budget(budget);
    const std::string label = "\"" + path + "\"";
    try {
        if (list) {
            std::vector<nl::VdbGridInfo> grids = nl::read_vdb_listing(path);
            return reply(rd::Status::Ok, nullptr, "", &grids);
        }
        if (fog_nvdb) { // a .nvdb level set, to be made a fog volume
            const bool index = !selector.empty() && selector.size() < 10 &&
                               std::all_of(selector.begin(), selector.end(),
                                           [](unsigned char c) { return std::isdigit(c); });
            if (!index)
                return reply(rd::Status::Error, nullptr,
                             label + ": a NanoVDB file's grid is asked for by its index, not \"" +
                                 selector + "\"");
            nl::VdbGrid grid = nl::read_nvdb_level_set_as_fog(path, uint32_t(std::stoul(selector)));
            return reply(rd::Status::Ok, &grid, "");
        }
        nl::VdbGrid grid = nl::read_vdb_grid(path, selector, !keep);
        return reply(rd::Status::Ok, &grid, "");
    } catch (const std::bad_alloc &) {
        return reply(rd::Status::OutOfBudget, nullptr,
                     rd::budget_refusal(label, budget, rd::heap_refused_bytes()));
    } catch (const nl::Error &e) {
        // (a std::bad_alloc inside OpenVDB may arrive wrapped in its message)
        if (rd::heap_refused_bytes() && std::strstr(e.what(), "bad_alloc"))
            return reply(rd::Status::OutOfBudget, nullptr,
                         rd::budget_refusal(label, budget, rd::heap_refused_bytes()));
        return reply(rd::Status::Error, nullptr, e.what());
    } catch (const std::exception &e) {
        return reply(rd::Status::Error, nullptr,
                     label + ": cannot read as an OpenVDB file (corrupt?): " + e.what());
    }
}
