// Output files under a temporary name. See temp_file.h.

#include "temp_file.h"

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <vector>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>

namespace vdb2nvdb {

namespace fs = std::filesystem;

namespace {
constexpr int kMaxTemps = 256;
char g_temp_paths[kMaxTemps][4096];
volatile std::sig_atomic_t g_temp_live[kMaxTemps];

extern "C" void on_fatal_signal(int sig) {
    for (int i = 0; i < kMaxTemps; ++i)
        if (g_temp_live[i])
            ::unlink(g_temp_paths[i]);
    std::signal(sig, SIG_DFL);
    std::raise(sig);
}
} // namespace

void install_signal_handlers() {
    std::signal(SIGINT, on_fatal_signal);
    std::signal(SIGTERM, on_fatal_signal);
    std::signal(SIGHUP, on_fatal_signal);
    // A crash (a damaged .vdb can crash OpenVDB's reader) leaves no
    // temporary file either; the parent process reports it (main.cpp)
    for (int sig : { SIGSEGV, SIGBUS, SIGABRT, SIGFPE, SIGILL })
        std::signal(sig, on_fatal_signal);
}

TempFile::TempFile(const std::string &path) : m_path(path) {
    if (path.empty())
        throw Error("empty output file name");
    fs::path p(path);
    std::error_code ec;
    if (fs::is_directory(p, ec))
        throw Error(dq(path) + ": is a directory; give an output file name");
    if (!p.has_filename())
        throw Error(dq(path) + ": not a file name");
    fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
    std::string templ = (dir / ("." + p.filename().string() + ".tmp-XXXXXX")).string();
    std::vector<char> buf(templ.begin(), templ.end());
    buf.push_back('\0');
    int fd = ::mkstemp(buf.data());
    if (fd < 0)
        throw Error("cannot write " + dq(path) + ": cannot create a file in " +
                    dq(dir.string()) + ": " + std::strerror(errno));
    // mkstemp creates mode 0600; give the file the usual 0666 & ~umask
    mode_t mask = ::umask(0);
    ::umask(mask);
    (void) ::fchmod(fd, 0666 & ~mask);
    ::close(fd);
    m_tmp = buf.data();
    if (m_tmp.size() < sizeof(g_temp_paths[0])) {
        for (int i = 0; i < kMaxTemps; ++i)
            if (!g_temp_live[i]) {
                std::memcpy(g_temp_paths[i], m_tmp.c_str(), m_tmp.size() + 1);
                g_temp_live[i] = 1;
                m_slot = i;
                break;
            }
    }
}

void TempFile::commit() {
    if (m_done)
        return;
    if (std::rename(m_tmp.c_str(), m_path.c_str()) != 0) {
        int err = errno;
        discard();
        throw Error("cannot write " + dq(m_path) + ": " + std::strerror(err));
    }
    m_done = true;
    if (m_slot >= 0)
        g_temp_live[m_slot] = 0;
}

void TempFile::discard() {
    if (m_done)
        return;
    ::unlink(m_tmp.c_str());
    m_done = true;
    if (m_slot >= 0)
        g_temp_live[m_slot] = 0;
}

TempFile::~TempFile() { discard(); }

} // namespace vdb2nvdb
