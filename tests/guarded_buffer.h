// tests/guarded_buffer.h -- a buffer whose end is followed by 16 GiB of
// PROT_NONE address space: all that a 32-bit word address can reach, so any
// read past the buffer faults, however far. Shared by the loader tests
// (tests/io/test_garbage_lookups.cpp) and the fuzzer (tests/fuzz/).
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

namespace nvdb_test {

class GuardedBuffer {
public:
    /// `bytes` (rounded up to 32), zeroed, 32-byte aligned, ending where the
    /// guard region begins
    explicit GuardedBuffer(uint64_t bytes) {
        const size_t page = size_t(sysconf(_SC_PAGESIZE));
        const size_t rounded = size_t((bytes + 31) / 32 * 32);
        const size_t head = (rounded + page - 1) / page * page;
        m_total = head + (size_t(1) << 34) + page;
        void *p = mmap(nullptr, m_total, PROT_NONE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
        if (p == MAP_FAILED)
            throw std::runtime_error("GuardedBuffer: mmap of " + std::to_string(m_total) +
                                     " bytes of address space failed");
        m_base = static_cast<uint8_t *>(p);
        if (head && mprotect(m_base, head, PROT_READ | PROT_WRITE) != 0) {
            munmap(m_base, m_total);
            throw std::runtime_error("GuardedBuffer: mprotect failed");
        }
        m_data = m_base + head - rounded; // 32-byte aligned (page - multiple of 32)
        m_size = rounded;
        std::memset(m_data, 0, rounded);
    }
    ~GuardedBuffer() { munmap(m_base, m_total); }
    GuardedBuffer(const GuardedBuffer &) = delete;
    GuardedBuffer &operator=(const GuardedBuffer &) = delete;

    uint8_t *data() const { return m_data; }
    /// The usable bytes (the request rounded up to 32)
    uint64_t size() const { return m_size; }

private:
    uint8_t *m_base = nullptr, *m_data = nullptr;
    size_t m_total = 0, m_size = 0;
};

} // namespace nvdb_test
