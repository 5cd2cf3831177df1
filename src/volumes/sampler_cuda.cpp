// The lookups of nanovdbvolume's CUDA variants (cuda_ad_rgb, cuda_ad_mono, ...),
// compiled once for all of them (nanovdb_drjit/sampler.h)
#include <drjit/autodiff.h>
#include <nanovdb_drjit/sampler_impl.h>

template class nanovdb_drjit::GridSampler<drjit::DiffArray<JitBackend::CUDA, float>>;
