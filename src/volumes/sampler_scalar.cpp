// The lookups of nanovdbvolume's scalar variants (scalar_rgb, scalar_spectral,
// ...), compiled once for all of them (nanovdb_drjit/sampler.h)
#include <nanovdb_drjit/sampler_impl.h>

template class nanovdb_drjit::GridSampler<float>;
