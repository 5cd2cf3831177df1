// vdb2nvdb: converts OpenVDB (.vdb) scalar float grids to NanoVDB (.nvdb) for
// Mitsuba's nanovdbvolume plugin, with NanoVDB's own converter
// (nanovdb::OpenToNanoVDB), and checks the written file against OpenVDB.
// `vdb2nvdb --help` and tools/vdb2nvdb/README.md describe the options.

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nanovdb_convert/format.h>
#include "convert.h"
#include "describe.h"
#include "generate.h"
#include "temp_file.h"
#include "testdata/generate_cases.h"

extern char **environ;

using namespace vdb2nvdb;

namespace {

const char *kUsage =
    "usage: vdb2nvdb [options] IN.vdb OUT.nvdb\n"
    "       vdb2nvdb --list IN.vdb\n"
    "       vdb2nvdb --verify-only [options] IN.vdb OUT.nvdb\n"
    "       vdb2nvdb generate CASE OUT.vdb [OUT.nvdb] [options]\n"
    "       vdb2nvdb generate --list\n";

void print_help() {
    std::printf("%s", kUsage);
    std::printf(
        "\n"
        "Converts every scalar float grid of an OpenVDB file to NanoVDB, in file order,\n"
        "keeping their names, with NanoVDB's own converter (nanovdb::OpenToNanoVDB).\n"
        "Grids of other types are skipped with a one-line notice. The output is written\n"
        "to a temporary file in the same directory, read back from disk, verified\n"
        "against OpenVDB and only then renamed into place: on any error no output file\n"
        "is left behind.\n"
        "\n"
        "Options:\n"
        "  --grid NAME          Convert only the grid(s) named NAME (repeatable; \"\" for\n"
        "                       an unnamed grid). An unknown name is an error that lists\n"
        "                       the file's grids; a non-float grid named here is an error.\n"
        "  --list               Print the file's grids (name, type, class, active voxel\n"
        "                       count, active index bbox, voxel size, what nanovdb-render\n"
        "                       makes of it: density, emission (temperature or radiance)\n"
        "                       or emission-like, unused; then per grid its world bbox,\n"
        "                       transform and active value range) and exit.\n"
        "  --keep-level-sets    Write level sets as they are. By default a level set\n"
        "                       becomes a fog volume (openvdb::tools::sdfToFogVolume: the\n"
        "                       interior narrow band becomes a 0..1 ramp, the interior 1\n"
        "                       (active), the exterior 0 (inactive)). Fog volumes and\n"
        "                       grids of other classes pass through unchanged.\n"
        "  --quantize TYPE      float (default), fp4, fp8, fp16 (fixed bit width per leaf,\n"
        "                       error <= half a step of (leaf max - leaf min) / (2^bits-1))\n"
        "                       or fpn (variable bit width per leaf, error <= --tolerance).\n"
        "                       The nanovdbvolume plugin reads float grids only for now.\n"
        "                       'half' is not available: NanoVDB 32.4 has no half-float\n"
        "                       leaf type (use fp16).\n"
        "  --tolerance T        Absolute error bound for fpn (default NanoVDB's: 0.01 for\n"
        "                       fog volumes, 0.1 x voxel size for level sets, 0 otherwise).\n"
        "  --codec C            none (default), zip or blosc compression of the .nvdb.\n"
        "  --verify N           Compare N random samples (a third active voxels and tiles,\n"
        "                       a third anywhere in the active bbox grown by 2 voxels, a\n"
        "                       third outside it, some up to the int32 extremes) between\n"
        "                       OpenVDB (after the fog conversion) and the written file\n"
        "                       read back with NanoVDB's reader: values bit-exact for\n"
        "                       float, within the quantization bound otherwise, and the\n"
        "                       active state. The whole grid is also validated (NanoVDB's\n"
        "                       GridValidator with a full checksum, name, background,\n"
        "                       active voxel count, bbox, transform). Default 100000;\n"
        "                       0 disables. A mismatch prints the coordinate and both\n"
        "                       values, removes the output and exits with status 3.\n"
        "  --seed S             Seed of the verification samples (default 1).\n"
        "  --verify-only        Check an existing OUT.nvdb against IN.vdb (same --grid,\n"
        "                       --keep-level-sets and --tolerance as the conversion).\n"
        "  --stats              Per grid: active voxels, active index bbox, voxel\n"
        "                       dimensions, node counts, active tiles, grid size, leaf\n"
        "                       share of it, dense-equivalent size (bbox voxels x 4 B),\n"
        "                       conversion time; and the .nvdb file size.\n"
        "  --dense OUT.vol      Also write the dense baseline for Mitsuba's gridvolume\n"
        "                       (.vol version 3, float32, 1 channel) over exactly the\n"
        "                       active index bbox [min, max], values read from the\n"
        "                       written .nvdb. Its bbox field is the world-space extent of\n"
        "                       the voxels' cells (the grid transform applied to the index\n"
        "                       box [min - 0.5, max + 0.5]). With several grids, one file\n"
        "                       per grid: OUT_<grid>.vol.\n"
        "  --max-dense-bytes B  Refuse a dense export larger than B bytes (suffix K, M, G,\n"
        "                       T = 2^10.. allowed). Default: half the physical memory.\n"
        "  --probe I,J,K        After writing, print the value and active state at index\n"
        "                       (I, J, K) as OpenVDB and as the written file read it\n"
        "                       (repeatable; a debugging aid).\n"
        "  --quiet              Print errors and notices only.\n"
        "  --help               This text.\n"
        "\n"
        "generate CASE OUT.vdb [OUT.nvdb]: writes a synthetic test volume with OpenVDB\n"
        "and, given OUT.nvdb, converts it with the options above. Cases:\n");
    for (const auto &c : nvdb_testdata::generate_cases())
        std::printf("  %-24s %s\n", c.first.c_str(), c.second.c_str());
    std::printf(
        "\n"
        "Exit status: 0 success, 1 error (bad input, unwritable output), 2 usage error,\n"
        "3 verification failure.\n");
}

[[noreturn]] void usage_error(const std::string &msg) {
    throw Error(msg + "\n" + kUsage + "(vdb2nvdb --help explains every option)", ExitUsage);
}

uint64_t parse_u64(const std::string &opt, const std::string &s) {
    if (s.empty() || s.find_first_not_of("0123456789") != std::string::npos)
        usage_error(opt + " needs a non-negative integer, not \"" + s + "\"");
    errno = 0;
    unsigned long long v = std::strtoull(s.c_str(), nullptr, 10);
    if (errno)
        usage_error(opt + ": \"" + s + "\" is out of range");
    return v;
}

uint64_t parse_bytes(const std::string &opt, std::string s) {
    uint64_t mult = 1;
    if (!s.empty()) {
        switch (s.back()) {
            case 'K': case 'k': mult = uint64_t(1) << 10; break;
            case 'M': case 'm': mult = uint64_t(1) << 20; break;
            case 'G': case 'g': mult = uint64_t(1) << 30; break;
            case 'T': case 't': mult = uint64_t(1) << 40; break;
            default: break;
        }
        if (mult != 1)
            s.pop_back();
    }
    uint64_t v = parse_u64(opt, s);
    if (v == 0)
        usage_error(opt + " must be positive");
    return v * mult;
}

openvdb::Coord parse_coord(const std::string &s) {
    int v[3];
    char tail;
    if (std::sscanf(s.c_str(), "%d,%d,%d%c", &v[0], &v[1], &v[2], &tail) != 3)
        usage_error("--probe needs I,J,K (three integers), not \"" + s + "\"");
    return openvdb::Coord(v[0], v[1], v[2]);
}

/// fn(), whose errors all name the input file: OpenVDB's and NanoVDB's own
/// messages from inside a conversion (a damaged transform: "Inversion of
/// singular 4x4 matrix") do not, and a user with many files needs the one
/// that failed
template <typename Fn> int naming_input(const std::string &in, Fn &&fn) {
    const std::string name = dq(in);
    try {
        return fn();
    } catch (const Error &e) {
        if (std::string(e.what()).find(name) != std::string::npos)
            throw;
        throw Error(name + ": " + e.what(), e.code);
    } catch (const std::bad_alloc &) {
        throw;
    } catch (const std::exception &e) {
        if (std::string(e.what()).find(name) != std::string::npos)
            throw;
        throw Error(name + ": " + e.what());
    }
}

int run(int argc, char **argv) {
    std::vector<std::string> args(argv + 1, argv + argc);
    Options opts;
    std::vector<std::string> positional;
    bool list = false, verify_only_mode = false, generate_mode = false, list_cases = false;

    if (!args.empty() && args[0] == "generate") {
        generate_mode = true;
        args.erase(args.begin());
    }
    for (size_t i = 0; i < args.size(); ++i) {
        std::string a = args[i], value;
        bool has_inline = false;
        if (a.rfind("--", 0) == 0 && a.find('=') != std::string::npos) {
            value = a.substr(a.find('=') + 1);
            a = a.substr(0, a.find('='));
            has_inline = true;
        }
        auto next = [&]() -> std::string {
            if (has_inline)
                return value;
            if (i + 1 >= args.size())
                usage_error(a + " needs a value");
            return args[++i];
        };
        if (a == "--help" || a == "-h") {
            print_help();
            return ExitOk;
        } else if (a == "--list") {
            (generate_mode ? list_cases : list) = true;
        } else if (a == "--grid") {
            opts.grids.push_back(next());
        } else if (a == "--keep-level-sets") {
            opts.keep_level_sets = true;
        } else if (a == "--quantize") {
            std::string q = next();
            if (q == "float") opts.quantize = Quantize::Float;
            else if (q == "fp4") opts.quantize = Quantize::Fp4;
            else if (q == "fp8") opts.quantize = Quantize::Fp8;
            else if (q == "fp16") opts.quantize = Quantize::Fp16;
            else if (q == "fpn") opts.quantize = Quantize::FpN;
            else if (q == "half")
                usage_error("--quantize half: NanoVDB 32.4 (Debian's libnanovdb-dev) has no "
                            "half-float leaf type (GridType::Half is declared but has no leaf "
                            "node nor converter); use --quantize fp16 (16-bit quantization per "
                            "leaf) instead");
            else
                usage_error("--quantize must be one of float, fp4, fp8, fp16, fpn; not \"" + q + "\"");
        } else if (a == "--tolerance") {
            std::string s = next();
            char *end = nullptr;
            float t = std::strtof(s.c_str(), &end);
            if (s.empty() || *end || !(t >= 0.f) || !std::isfinite(t))
                usage_error("--tolerance needs a non-negative number, not \"" + s + "\"");
            opts.tolerance = t;
        } else if (a == "--codec") {
            std::string c = next();
            if (c == "none") opts.codec = nanovdb::io::Codec::NONE;
            else if (c == "zip") opts.codec = nanovdb::io::Codec::ZIP;
            else if (c == "blosc") opts.codec = nanovdb::io::Codec::BLOSC;
            else usage_error("--codec must be one of none, zip, blosc; not \"" + c + "\"");
        } else if (a == "--verify") {
            opts.verify = parse_u64(a, next());
        } else if (a == "--seed") {
            opts.seed = parse_u64(a, next());
        } else if (a == "--verify-only") {
            verify_only_mode = true;
        } else if (a == "--stats") {
            opts.stats = true;
        } else if (a == "--dense") {
            opts.dense = next();
            if (opts.dense.empty())
                usage_error("--dense needs a file name");
        } else if (a == "--max-dense-bytes") {
            opts.max_dense_bytes = parse_bytes(a, next());
        } else if (a == "--probe") {
            opts.probes.push_back(parse_coord(next()));
        } else if (a == "--corrupt-for-test") { // hidden: tests that --verify catches a bug
            opts.corrupt_for_test = true;
        } else if (a == "--quiet" || a == "-q") {
            opts.quiet = true;
        } else if (a.size() > 1 && a[0] == '-') {
            usage_error("unknown option \"" + a + "\"");
        } else {
            positional.push_back(a);
        }
    }

    if (opts.tolerance >= 0.f && opts.quantize != Quantize::FpN)
        usage_error("--tolerance applies to --quantize fpn only");

    if (generate_mode) {
        if (list_cases) {
            for (const auto &c : nvdb_testdata::generate_cases())
                std::printf("%-24s %s\n", c.first.c_str(), c.second.c_str());
            return ExitOk;
        }
        if (positional.size() < 2 || positional.size() > 3)
            usage_error("generate needs CASE OUT.vdb [OUT.nvdb]");
        return generate(positional[0], positional[1], positional.size() == 3 ? positional[2] : "",
                        opts);
    }
    if (list) {
        if (positional.size() != 1)
            usage_error("--list needs exactly one file, IN.vdb");
        return naming_input(positional[0], [&] { return list_file(positional[0]); });
    }
    if (positional.size() != 2)
        usage_error(positional.size() < 2 ? "missing IN.vdb and/or OUT.nvdb"
                                          : "too many file names");
    if (verify_only_mode)
        return naming_input(positional[0],
                            [&] { return verify_only(positional[0], positional[1], opts); });
    return naming_input(positional[0],
                        [&] { return convert_file(positional[0], positional[1], opts); });
}

int work(int argc, char **argv) {
    install_signal_handlers();
    try {
        openvdb::initialize();
        return run(argc, argv);
    } catch (const Error &e) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: %s\n", e.what());
        return e.code;
    } catch (const std::bad_alloc &) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: out of memory\n");
        return ExitError;
    } catch (const std::exception &e) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: %s\n", e.what());
        return ExitError;
    }
}

// The work runs in a child process: this program started again, with
// NVDB_VDB2NVDB_IN_PROCESS=1. OpenVDB's reader trusts its stream, and a
// damaged file can corrupt the heap (src/loader/vdb_import.cpp). A crash
// then ends the child, which removes its temporary outputs (temp_file.cpp),
// and this process says what happened, instead of an abort in glibc's
// words. (A fresh process, not fork(): OpenVDB's logging library starts a
// thread when it is loaded, which a forked child would lack, and wait for
// at exit.)
volatile std::sig_atomic_t g_child = 0;

extern "C" void forward_signal(int sig) {
    if (g_child > 0)
        ::kill(pid_t(g_child), sig);
}

/// The input named on the command line: its first existing file
std::string input_name(int argc, char **argv) {
    std::error_code ec;
    for (int i = 1; i < argc; ++i)
        if (argv[i][0] != '-' && std::filesystem::is_regular_file(argv[i], ec))
            return argv[i];
    return "the input";
}

} // namespace

int main(int argc, char **argv) {
    // (NVDB_VDB2NVDB_IN_PROCESS=1: the child; set by hand, no child, for debuggers)
    const char *in_process = std::getenv("NVDB_VDB2NVDB_IN_PROCESS");
    if (in_process && std::string(in_process) == "1")
        return work(argc, argv);
    std::fflush(nullptr);
    pid_t pid = -1;
    ::setenv("NVDB_VDB2NVDB_IN_PROCESS", "1", 1);
    if (::posix_spawn(&pid, "/proc/self/exe", nullptr, nullptr, argv, environ) != 0) {
        ::unsetenv("NVDB_VDB2NVDB_IN_PROCESS");
        return work(argc, argv); // (no /proc: in this process)
    }
    g_child = pid;
    for (int sig : { SIGINT, SIGTERM, SIGHUP })
        std::signal(sig, forward_signal);
    // A deadline where there is an input file (not for `generate`): 300 s
    // and 10 s per MiB, NVDB_VDB2NVDB_TIMEOUT seconds instead. No damaged
    // file known makes the read loop now (the root counts are checked
    // first), but nothing should hang a batch job if one does.
    const std::string input = input_name(argc, argv);
    double timeout = 0;
    std::error_code ec;
    if (std::filesystem::is_regular_file(input, ec))
        timeout = 300.0 + 10.0 * double(std::filesystem::file_size(input, ec)) / (1 << 20);
    if (const char *t = std::getenv("NVDB_VDB2NVDB_TIMEOUT"))
        timeout = std::atof(t);
    const auto deadline = std::chrono::steady_clock::now() +
                          std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                              std::chrono::duration<double>(timeout));
    int status = 0;
    for (;;) {
        pid_t r = ::waitpid(pid, &status, timeout > 0 ? WNOHANG : 0);
        if (r == pid)
            break;
        if (r < 0 && errno != EINTR)
            return ExitError;
        if (r == 0) {
            if (std::chrono::steady_clock::now() > deadline) {
                ::kill(pid, SIGTERM); // (the child removes its temporary outputs)
                ::waitpid(pid, &status, 0);
                std::fprintf(stderr,
                             "vdb2nvdb: error: %s: damaged or hostile: reading it took longer "
                             "than %g s and was stopped (NVDB_VDB2NVDB_TIMEOUT sets the "
                             "limit); no output was written\n",
                             dq(input).c_str(), timeout);
                return ExitError;
            }
            ::usleep(20000);
        }
    }
    if (WIFEXITED(status))
        return WEXITSTATUS(status);
    const int sig = WTERMSIG(status);
    if (sig == SIGINT || sig == SIGTERM || sig == SIGHUP) {
        std::signal(sig, SIG_DFL);
        std::raise(sig);
    }
    const char *abbrev = sigabbrev_np(sig);
    std::fprintf(stderr,
                 "vdb2nvdb: error: %s: damaged: OpenVDB's reader crashed on it (SIG%s); no "
                 "output was written\n",
                 dq(input_name(argc, argv)).c_str(), abbrev ? abbrev : "?");
    return ExitError;
}
