// The lookups of nanovdbvolume's LLVM variants (llvm_ad_rgb, llvm_ad_mono, ...),
// compiled once for all of them (nanovdb_drjit/sampler.h)
#include <drjit/autodiff.h>
#include <nanovdb_drjit/sampler_impl.h>

template class nanovdb_drjit::GridSampler<drjit::DiffArray<JitBackend::LLVM, float>>;
