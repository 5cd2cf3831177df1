// An OpenVDB file's grid as NanoVDB bytes, or its list of grids, or a
// NanoVDB level set made a fog volume, read in a separate process (see
// nanovdb_loader/vdb_import.h).
//
// Why a process: OpenVDB's reader trusts its stream. Damaged files were
// seen to reach malloc and free with garbage sizes ("malloc(): invalid
// size", "double free or corruption") and to drive a load to 10 GB. Those
// bugs are in OpenVDB's templates, inside a format with no checksums, so
// no check made from outside can be shown to stop them all: validating
// the stream first would mean a second, complete parser of every version
// of the format. A process of its own contains them whatever they are:
//  * nanovdb-vdb-reader (vdb_reader_main.cpp) reads and converts the grid
//    under a memory budget (vdb_reader_budget.h) and sends the NanoVDB
//    buffer back on a pipe (vdb_reader_protocol.h);
//  * this side waits with a deadline, caps every length it reads, and
//    turns a crash, a refusal or a timeout into an Error that names the
//    file and says it is damaged;
//  * the buffer then goes through the .nvdb validation (validate_grid),
//    as a file's grid does, before any lookup touches it.
// What it costs is a process start and a copy through the pipe: measured
// in bench/vdb_load.py (PERF_LOG 27).

#include <nanovdb_loader/vdb_import.h>

#include <algorithm>
#include <cctype>
#include <filesystem>

#if defined(NVDB_WITH_OPENVDB)
#include "vdb_reader_budget.h"
#include "vdb_reader_protocol.h"

#include <dlfcn.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <vector>

extern char **environ;
#endif

namespace nanovdb_loader {

namespace fs = std::filesystem;

bool is_vdb_path(const std::string &path) {
    std::string ext = fs::path(path).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return (char) std::tolower(c); });
    return ext == ".vdb";
}

#if !defined(NVDB_WITH_OPENVDB)

bool vdb_import_available() { return false; }

VdbGrid import_vdb_grid(const std::string &path, const std::string &, bool) {
    throw Error("\"" + path + "\": an OpenVDB file, and this build of nanovdbvolume has no "
                "OpenVDB: convert it with vdb2nvdb, or install libopenvdb-dev (and "
                "libboost-dev libtbb-dev libimath-dev) and rebuild");
}

VdbGrid import_nvdb_level_set_as_fog(const std::string &path, uint32_t, const std::string &) {
    throw Error("\"" + path + "\": a level set made a fog volume needs OpenVDB, which this "
                "build of nanovdbvolume lacks: set level_set=\"distance\", or install "
                "libopenvdb-dev (and libboost-dev libtbb-dev libimath-dev) and rebuild");
}

std::vector<VdbGridInfo> list_vdb_grids(const std::string &path) {
    import_vdb_grid(path, "");
    return {};
}

#else

bool vdb_import_available() { return true; }

namespace {

namespace rd = vdb_reader;
using Clock = std::chrono::steady_clock;

/// nanovdb-vdb-reader: NVDB_VDB_READER, else beside the library that holds
/// this code (a plugin in plugins/, the reader in bin/, in the build tree
/// and in the installed package alike)
std::string reader_path() {
    if (const char *p = std::getenv("NVDB_VDB_READER"); p && *p)
        return p;
    Dl_info info{};
    std::vector<fs::path> tried;
    if (dladdr((void *) &reader_path, &info) && info.dli_fname) {
        std::error_code ec;
        fs::path self = fs::canonical(info.dli_fname, ec);
        if (!ec)
            for (const fs::path &p : { self.parent_path().parent_path() / "bin",
                                       self.parent_path() }) {
                fs::path candidate = p / "nanovdb-vdb-reader";
                if (::access(candidate.c_str(), X_OK) == 0)
                    return candidate.string();
                tried.push_back(candidate);
            }
    }
    std::string where;
    for (const fs::path &p : tried)
        where += (where.empty() ? "" : ", ") + p.string();
    throw Error("nanovdb-vdb-reader, which reads .vdb files for nanovdbvolume, is not "
                "installed beside the plugin (looked for " + where + "); set "
                "NVDB_VDB_READER to its path, or reinstall nanovdb-mitsuba");
}

/// Seconds the reader may take: NVDB_VDB_READER_TIMEOUT, else 60 s and 2 s
/// per MiB (an intact 74 MB grid takes ~1.5 s)
double timeout_seconds(uint64_t file_bytes) {
    if (const char *s = std::getenv("NVDB_VDB_READER_TIMEOUT")) {
        char *end = nullptr;
        double v = std::strtod(s, &end);
        if (end != s && *end == '\0' && v > 0)
            return v;
    }
    return 60.0 + 2.0 * double(file_bytes) / double(1 << 20);
}

struct Fd {
    int fd = -1;
    Fd() = default;
    explicit Fd(int f) : fd(f) {}
    Fd(const Fd &) = delete;
    Fd &operator=(const Fd &) = delete;
    ~Fd() { reset(); }
    void reset() {
        if (fd >= 0)
            ::close(fd);
        fd = -1;
    }
};

/// The child, waited for whatever happens (no zombie, no orphan)
struct Child {
    pid_t pid = -1;
    int status = 0;
    bool waited = false;
    void kill_and_wait() {
        if (pid > 0 && !waited)
            ::kill(pid, SIGKILL);
        wait();
    }
    void wait() {
        if (pid <= 0 || waited)
            return;
        waited = true;
        while (::waitpid(pid, &status, 0) < 0) {
            if (errno != EINTR) { // (SIGCHLD ignored by the host: no status)
                status = 0;
                return;
            }
        }
    }
    ~Child() { kill_and_wait(); }
};

std::string signal_text(int sig) {
    const char *d = strsignal(sig);
    return std::string(sigabbrev_np(sig) ? "SIG" + std::string(sigabbrev_np(sig)) : "signal " +
                       std::to_string(sig)) + (d ? std::string(" (") + d + ")" : "");
}

/// The last line or two of what the reader printed, for the message
std::string tail_text(const std::string &err) {
    std::string s = err;
    while (!s.empty() && std::isspace((unsigned char) s.back()))
        s.pop_back();
    size_t cut = s.size() > 300 ? s.size() - 300 : 0;
    s = s.substr(cut);
    for (char &c : s)
        if (c == '\n' || c == '\r')
            c = ' ';
    return s.empty() ? "" : ": it printed \"" + printable_text(s) + "\"";
}

/// Reads the child's reply and its output until both pipes close, the
/// reply grows past `cap`, or the deadline passes
struct Transfer {
    std::vector<uint8_t> reply;
    std::string err;
    bool too_long = false, timed_out = false;
};

Transfer transfer(int reply_fd, int err_fd, uint64_t cap, Clock::time_point deadline) {
    Transfer t;
    pollfd fds[2] = { { reply_fd, POLLIN, 0 }, { err_fd, POLLIN, 0 } };
    char scratch[4096];
    // The reply is read straight into its buffer: the header first, which
    // sizes the buffer once, then the rest (no second copy of the grid)
    t.reply.resize(sizeof(rd::Reply));
    size_t filled = 0;
    bool have_header = false;
    while (fds[0].fd >= 0 || fds[1].fd >= 0) {
        auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
        if (left.count() <= 0) {
            t.timed_out = true;
            return t;
        }
        int n = ::poll(fds, 2, int(std::min<int64_t>(left.count(), 1000)));
        if (n < 0 && errno != EINTR)
            return t;
        for (pollfd &p : fds) {
            if (p.fd < 0 || !(p.revents & (POLLIN | POLLHUP | POLLERR)))
                continue;
            ssize_t got;
            if (&p == &fds[0] && filled < t.reply.size()) {
                got = ::read(p.fd, t.reply.data() + filled, t.reply.size() - filled);
                if (got > 0)
                    filled += size_t(got);
                if (!have_header && filled == sizeof(rd::Reply)) {
                    have_header = true;
                    rd::Reply r;
                    std::memcpy(&r, t.reply.data(), sizeof r);
                    if (r.grid_bytes > cap) {
                        t.too_long = true;
                        return t;
                    }
                    t.reply.resize(sizeof r + std::min(r.name_bytes, rd::kMaxText) +
                                   std::min(r.message_bytes, rd::kMaxText) + r.grid_bytes);
                }
            } else if (&p == &fds[0]) { // the reply is complete: only its end may follow
                got = ::read(p.fd, scratch, sizeof scratch);
                if (got > 0) {
                    t.too_long = true;
                    return t;
                }
            } else {
                got = ::read(p.fd, scratch, sizeof scratch);
                if (got > 0) {
                    t.err.append(scratch, size_t(got));
                    if (t.err.size() > 8192)
                        t.err.erase(0, t.err.size() - 4096);
                }
            }
            if (got == 0 || (got < 0 && errno != EINTR && errno != EAGAIN))
                p.fd = -1;
        }
    }
    t.reply.resize(filled); // (a reply cut short is found malformed by the caller)
    return t;
}

/// A checked reply of the reader: its header, the bytes after it (name,
/// message, payload), and the time from start to reply
struct Answer {
    rd::Reply r;
    std::vector<uint8_t> bytes;
    double seconds = 0;
    const char *text() const { return (const char *) bytes.data() + sizeof r; }
    size_t payload_offset() const { return sizeof r + r.name_bytes + r.message_bytes; }
};

/// Starts the reader on `args` (about the file `path`) and waits for its
/// reply; every way it can fail (no start, a crash, a timeout, a malformed
/// or oversized reply, an error it reports) is an Error naming the file
Answer ask_reader(const std::string &path, const std::vector<std::string> &args) {
    const std::string label = "\"" + path + "\"";
    std::error_code ec;
    if (!fs::is_regular_file(path, ec))
        throw Error(label + (fs::exists(path, ec) ? ": not a regular file" : ": no such file"));
    const uint64_t file_bytes = fs::file_size(path, ec);
    const std::string reader = reader_path();
    const auto t0 = Clock::now();

    int reply_pipe[2], err_pipe[2];
    if (::pipe2(reply_pipe, O_CLOEXEC) != 0)
        throw Error(label + ": cannot start the .vdb reader: pipe: " + std::strerror(errno));
    Fd reply_r(reply_pipe[0]), reply_w(reply_pipe[1]);
    if (::pipe2(err_pipe, O_CLOEXEC) != 0)
        throw Error(label + ": cannot start the .vdb reader: pipe: " + std::strerror(errno));
    Fd err_r(err_pipe[0]), err_w(err_pipe[1]);

    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_adddup2(&actions, err_w.fd, 1);
    posix_spawn_file_actions_adddup2(&actions, err_w.fd, 2);
    posix_spawn_file_actions_adddup2(&actions, reply_w.fd, rd::kReplyFd);
    std::vector<char *> argv = { const_cast<char *>(reader.c_str()) };
    for (const std::string &a : args)
        argv.push_back(const_cast<char *>(a.c_str()));
    argv.push_back(nullptr);
    Child child;
    int rc = ::posix_spawn(&child.pid, reader.c_str(), &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) {
        child.pid = -1;
        throw Error(label + ": cannot start the .vdb reader " + reader + ": " + std::strerror(rc));
    }
    reply_w.reset();
    err_w.reset();

    const double timeout = timeout_seconds(file_bytes);
    const uint64_t cap = rd::memory_budget(file_bytes);
    Transfer t = transfer(reply_r.fd, err_r.fd, cap,
                          t0 + std::chrono::duration_cast<Clock::duration>(
                                   std::chrono::duration<double>(timeout)));
    child.kill_and_wait();
    const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();

    if (t.timed_out)
        throw Error(label + ": damaged or hostile: its reader took longer than " +
                    std::to_string(int(timeout)) + " s and was stopped "
                    "(NVDB_VDB_READER_TIMEOUT sets the limit in seconds)");
    if (t.too_long)
        throw Error(label + ": damaged: its reader sent more than a file of its size can "
                    "hold");
    if (WIFSIGNALED(child.status))
        throw Error(label + ": damaged: OpenVDB's reader crashed on it with " +
                    signal_text(WTERMSIG(child.status)) + tail_text(t.err) +
                    ". The reader runs in a process of its own (nanovdb-vdb-reader); "
                    "nothing else was affected");

    rd::Reply r;
    if (t.reply.size() < sizeof r)
        throw Error(label + ": the .vdb reader " + reader + " ended without a reply (exit " +
                    std::to_string(WIFEXITED(child.status) ? WEXITSTATUS(child.status) : -1) +
                    ")" + tail_text(t.err));
    std::memcpy(&r, t.reply.data(), sizeof r);
    const uint64_t body = uint64_t(r.name_bytes) + r.message_bytes + r.grid_bytes;
    if (std::memcmp(r.magic, rd::kMagic, sizeof r.magic) != 0 || r.name_bytes > rd::kMaxText ||
        r.message_bytes > rd::kMaxText || t.reply.size() != sizeof r + body)
        throw Error(label + ": the .vdb reader " + reader + " sent a malformed reply (exit " +
                    std::to_string(WIFEXITED(child.status) ? WEXITSTATUS(child.status) : -1) +
                    ")" + tail_text(t.err));
    const char *text = (const char *) t.reply.data() + sizeof r;
    if (r.status != rd::Status::Ok)
        throw Error(printable_text(std::string(text + r.name_bytes, r.message_bytes)));

    Answer answer{ r, std::move(t.reply), seconds };
    return answer;
}

/// The grid a reply carries
VdbGrid grid_of(Answer &&a) {
    VdbGrid out;
    out.name = printable_text(std::string(a.text(), a.r.name_bytes));
    out.index = a.r.index;
    out.source_class = a.r.source_class;
    out.fogged = a.r.fogged != 0;
    out.read_seconds = a.r.read_seconds;
    out.convert_seconds = a.r.convert_seconds;
    out.reader_seconds = a.seconds;
    out.reader_peak_bytes = a.r.peak_bytes;
    out.size = size_t(a.r.grid_bytes);
    // The grid bytes stay in the reply's vector (no second copy); the
    // plugin copies them once, into the block its backend owns
    const size_t offset = a.payload_offset();
    auto owner = std::make_shared<std::vector<uint8_t>>(std::move(a.bytes));
    out.data = std::shared_ptr<const uint8_t>(owner, owner->data() + offset);
    return out;
}

} // namespace

VdbGrid import_vdb_grid(const std::string &path, const std::string &selector,
                        bool fog_level_sets) {
    std::vector<std::string> args = { path, selector };
    if (!fog_level_sets)
        args.push_back("--keep-level-sets");
    return grid_of(ask_reader(path, args));
}

VdbGrid import_nvdb_level_set_as_fog(const std::string &path, uint32_t index,
                                     const std::string &name) {
    VdbGrid g = grid_of(ask_reader(path, { "--fog-nvdb", path, std::to_string(index) }));
    // NanoVDB's reader and ours must agree on which grid is `index`
    if (g.name != printable_text(name))
        throw Error("\"" + path + "\": the .vdb reader read grid " + std::to_string(index) +
                    " as \"" + g.name + "\", not \"" + printable_text(name) +
                    "\": NanoVDB's reader counts this file's grids differently");
    return g;
}

std::vector<VdbGridInfo> list_vdb_grids(const std::string &path) {
    Answer a = ask_reader(path, { "--list", path });
    const std::string label = "\"" + path + "\"";
    std::vector<VdbGridInfo> out;
    size_t at = a.payload_offset();
    for (uint32_t i = 0; i < a.r.entries; ++i) {
        rd::ListEntry e;
        if (a.bytes.size() - at < sizeof e)
            throw Error(label + ": the .vdb reader sent a malformed listing");
        std::memcpy(&e, a.bytes.data() + at, sizeof e);
        at += sizeof e;
        if (e.name_bytes > rd::kMaxText || e.type_bytes > rd::kMaxText ||
            a.bytes.size() - at < uint64_t(e.name_bytes) + e.type_bytes)
            throw Error(label + ": the .vdb reader sent a malformed listing");
        const char *p = (const char *) a.bytes.data() + at;
        out.push_back({ printable_text(std::string(p, e.name_bytes)),
                        printable_text(std::string(p + e.name_bytes, e.type_bytes)),
                        e.grid_class });
        at += e.name_bytes + e.type_bytes;
    }
    if (at != a.bytes.size())
        throw Error(label + ": the .vdb reader sent a malformed listing");
    return out;
}

#endif

} // namespace nanovdb_loader
