/*
    nanovdb_drjit/backend_buffer.h -- the grid in the backend's memory, at its
    exact size

    Dr.Jit's allocator (jit_malloc) rounds every allocation up to a power of
    two: a 5.4 MB grid takes 8 MiB, a 3.4 GB grid 4 GiB. A grid is held for
    the lifetime of a volume and never resized, so these functions allocate
    it at its own size instead and hand it to Dr.Jit with jit_var_mem_map().
    Dr.Jit reads the memory in place and tells us, through a variable
    callback, when the last reference is gone; the memory is released only
    after every kernel launched before that point has finished.

      - LLVM: the kernels read host memory. The caller decodes the grid
        straight into a posix_memalign() block, which map_host_words() maps
        (no copy at all).
      - CUDA: the caller decodes into host memory; upload_cuda_words() makes
        one cuMemAlloc() of the exact size, copies, and maps it. The host
        staging buffer can be freed as soon as it returns. The CUDA driver is
        reached through Dr.Jit's own handle (jit_cuda_lookup), so the plugin
        does not link against libcuda and loads on machines without a GPU.

    Both return a new Dr.Jit variable index with reference count 1 (wrap it
    with `UInt32::steal`).
*/

#pragma once

#include <drjit-core/jit.h>

#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

namespace nanovdb_drjit::backend {

/// Maps a posix_memalign()'ed block of `words` 32-bit words as an LLVM
/// variable that owns it: freed after the kernels that use it have finished.
inline uint32_t map_host_words(void *ptr, size_t words) {
    uint32_t index = jit_var_mem_map(JitBackend::LLVM, VarType::UInt32, ptr, words, 0);
    // Called without Dr.Jit's lock held, when the variable is freed
    jit_var_set_callback(
        index,
        [](uint32_t, int free, void *p) {
            if (free)
                jit_enqueue_host_func(JitBackend::LLVM, [](void *q) { std::free(q); }, p);
        },
        ptr);
    return index;
}

namespace detail {

// The few CUDA driver API entry points we need (cuda.h is not required)
using CUresult = int;
using CUdeviceptr = unsigned long long;
using CUcontext = void *;

struct CudaDriver {
    CUresult (*mem_alloc)(CUdeviceptr *, size_t);
    CUresult (*mem_free)(CUdeviceptr);
    CUresult (*memcpy_htod)(CUdeviceptr, const void *, size_t);
    CUresult (*ctx_push)(CUcontext);
    CUresult (*ctx_pop)(CUcontext *);
    CUresult (*ctx_synchronize)();
    CUresult (*error_name)(CUresult, const char **);

    static const CudaDriver &get() {
        static const CudaDriver d = [] {
            CudaDriver r;
            r.mem_alloc = (decltype(r.mem_alloc)) jit_cuda_lookup("cuMemAlloc_v2");
            r.mem_free = (decltype(r.mem_free)) jit_cuda_lookup("cuMemFree_v2");
            r.memcpy_htod = (decltype(r.memcpy_htod)) jit_cuda_lookup("cuMemcpyHtoD_v2");
            r.ctx_push = (decltype(r.ctx_push)) jit_cuda_lookup("cuCtxPushCurrent_v2");
            r.ctx_pop = (decltype(r.ctx_pop)) jit_cuda_lookup("cuCtxPopCurrent_v2");
            r.ctx_synchronize = (decltype(r.ctx_synchronize)) jit_cuda_lookup("cuCtxSynchronize");
            r.error_name = (decltype(r.error_name)) jit_cuda_lookup("cuGetErrorName");
            return r;
        }();
        return d;
    }

    std::string describe(CUresult rv) const {
        const char *name = nullptr;
        if (error_name(rv, &name) != 0 || !name)
            return "CUDA error " + std::to_string(rv);
        return name;
    }
};

/// Makes Dr.Jit's CUDA context current for the scope
struct ScopedContext {
    const CudaDriver &d;
    explicit ScopedContext(const CudaDriver &d, CUcontext ctx) : d(d) { d.ctx_push(ctx); }
    ~ScopedContext() {
        CUcontext unused;
        d.ctx_pop(&unused);
    }
};

struct DeviceBlock {
    CUdeviceptr ptr;
    CUcontext ctx;
};

/// Variable callback: when the grid's variable dies, wait for the kernels
/// that may still read it, then release it. Never throws (it may run late
/// during shutdown, when nothing can be reported any more).
inline void release_device_block(uint32_t, int free, void *data) {
    if (!free)
        return;
    DeviceBlock *block = (DeviceBlock *) data;
    const CudaDriver &d = CudaDriver::get();
    {
        ScopedContext guard(d, block->ctx);
        d.ctx_synchronize();
        d.mem_free(block->ptr);
    }
    delete block;
}

} // namespace detail

/// Copies `bytes` from host memory `src` into one device allocation of
/// exactly `bytes` (rounded up to whole words; the caller pads `src` to
/// `words` words) and maps it as a CUDA variable of `words` 32-bit words.
/// Throws std::runtime_error naming the CUDA error.
inline uint32_t upload_cuda_words(const void *src, size_t words) {
    using namespace detail;
    const CudaDriver &d = CudaDriver::get();
    size_t bytes = words * 4;
    CUcontext ctx = (CUcontext) jit_cuda_context();
    CUdeviceptr ptr = 0;
    CUresult rv;
    {
        ScopedContext guard(d, ctx);
        rv = d.mem_alloc(&ptr, bytes);
    }
    if (rv != 0) {
        // Memory cached by Dr.Jit's allocator may be what is missing
        jit_flush_malloc_cache();
        ScopedContext guard(d, ctx);
        rv = d.mem_alloc(&ptr, bytes);
    }
    if (rv != 0)
        throw std::runtime_error("cannot allocate " + std::to_string(bytes) +
                                 " bytes of GPU memory (" + d.describe(rv) + ")");
    {
        ScopedContext guard(d, ctx);
        rv = d.memcpy_htod(ptr, src, bytes);
        // A copy from pageable memory may return before its DMA has landed;
        // Dr.Jit's kernels run on another stream, so wait for it here.
        if (rv == 0)
            rv = d.ctx_synchronize();
        if (rv != 0) {
            d.mem_free(ptr);
            throw std::runtime_error("cannot copy " + std::to_string(bytes) +
                                     " bytes to the GPU (" + d.describe(rv) + ")");
        }
    }
    uint32_t index = jit_var_mem_map(JitBackend::CUDA, VarType::UInt32, (void *) ptr, words, 0);
    jit_var_set_callback(index, release_device_block, new DeviceBlock{ ptr, ctx });
    return index;
}

} // namespace nanovdb_drjit::backend
