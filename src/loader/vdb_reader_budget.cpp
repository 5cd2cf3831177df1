// The memory budget of a .vdb reader (vdb_reader_budget.h): operator new
// and delete replaced for the whole process. Linked into nanovdb-vdb-reader
// and the .vdb fuzzer only, never into a plugin.
//
// Each block carries its size in a 16-byte header (malloc's alignment is
// kept), so that delete can give it back to the count. The aligned forms
// (align_val_t) are libstdc++'s own, outside the count: OpenVDB's reader
// does not use them, and RLIMIT_DATA still caps them.

#include "vdb_reader_budget.h"

#include <atomic>
#include <cstdlib>
#include <new>
#include <string>

namespace nanovdb_loader::vdb_reader {

namespace {

constexpr size_t kHeader = 16;
std::atomic<uint64_t> g_live{ 0 }, g_peak{ 0 }, g_refused{ 0 };
std::atomic<uint64_t> g_budget{ UINT64_MAX };

void *budget_alloc(size_t n) noexcept {
    const uint64_t want = uint64_t(n) + kHeader;
    const uint64_t budget = g_budget.load(std::memory_order_relaxed);
    // Refused before anything is allocated: a single garbage size, or one
    // that would take the live total past the budget
    uint64_t live = g_live.fetch_add(want, std::memory_order_relaxed) + want;
    if (n > budget || live > budget) {
        g_live.fetch_sub(want, std::memory_order_relaxed);
        uint64_t r = g_refused.load(std::memory_order_relaxed);
        while (n > r && !g_refused.compare_exchange_weak(r, n)) {}
        return nullptr;
    }
    void *raw = std::malloc(size_t(want));
    if (!raw) {
        g_live.fetch_sub(want, std::memory_order_relaxed);
        return nullptr;
    }
    uint64_t peak = g_peak.load(std::memory_order_relaxed);
    while (live > peak && !g_peak.compare_exchange_weak(peak, live)) {}
    *static_cast<uint64_t *>(raw) = want;
    return static_cast<char *>(raw) + kHeader;
}

void budget_free(void *p) noexcept {
    if (!p)
        return;
    char *raw = static_cast<char *>(p) - kHeader;
    g_live.fetch_sub(*reinterpret_cast<uint64_t *>(raw), std::memory_order_relaxed);
    std::free(raw);
}

void *budget_new(size_t n) {
    void *p = budget_alloc(n);
    if (!p)
        throw std::bad_alloc();
    return p;
}

} // namespace

void set_heap_budget(uint64_t bytes) {
    g_budget.store(bytes);
    g_peak.store(g_live.load());
}
ScopedHeapBudget::ScopedHeapBudget(uint64_t bytes) : previous(g_budget.load()) {
    g_refused.store(0);
    // (what is live already counts: the budget is for what the scope adds)
    const uint64_t live = g_live.load();
    set_heap_budget(bytes > UINT64_MAX - live ? UINT64_MAX : live + bytes);
}
ScopedHeapBudget::~ScopedHeapBudget() { g_budget.store(previous); }

uint64_t heap_live_bytes() { return g_live.load(); }
uint64_t heap_peak_bytes() { return g_peak.load(); }
uint64_t heap_refused_bytes() { return g_refused.load(); }

} // namespace nanovdb_loader::vdb_reader

namespace budget = nanovdb_loader::vdb_reader;

void *operator new(size_t n) { return budget::budget_new(n); }
void *operator new[](size_t n) { return budget::budget_new(n); }
void *operator new(size_t n, const std::nothrow_t &) noexcept { return budget::budget_alloc(n); }
void *operator new[](size_t n, const std::nothrow_t &) noexcept { return budget::budget_alloc(n); }
void operator delete(void *p) noexcept { budget::budget_free(p); }
void operator delete[](void *p) noexcept { budget::budget_free(p); }
void operator delete(void *p, size_t) noexcept { budget::budget_free(p); }
void operator delete[](void *p, size_t) noexcept { budget::budget_free(p); }
void operator delete(void *p, const std::nothrow_t &) noexcept { budget::budget_free(p); }
void operator delete[](void *p, const std::nothrow_t &) noexcept { budget::budget_free(p); }
