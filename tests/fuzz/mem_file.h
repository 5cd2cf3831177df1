// tests/fuzz/mem_file.h -- a fuzz input as a file: a memfd, named by its
// /proc/self/fd path, read exactly as the plugin reads a file (both
// harnesses: fuzz_nvdb.cpp, fuzz_vdb.cpp).
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace nvdb_fuzz {

struct MemFile {
    int fd = -1;
    std::string path;
    MemFile(const uint8_t *data, size_t size) {
        fd = memfd_create("nvdb_fuzz", 0);
        if (fd < 0)
            fail("memfd_create failed");
        size_t done = 0;
        while (done < size) {
            const ssize_t n = write(fd, data + done, size - done);
            if (n <= 0)
                fail("write to memfd failed");
            done += size_t(n);
        }
        path = "/proc/self/fd/" + std::to_string(fd);
    }
    ~MemFile() { close(fd); }
    MemFile(const MemFile &) = delete;
    MemFile &operator=(const MemFile &) = delete;

private:
    [[noreturn]] static void fail(const char *what) {
        std::fprintf(stderr, "fuzz: %s\n", what);
        std::abort();
    }
};

} // namespace nvdb_fuzz
