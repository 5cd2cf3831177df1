/*
    nanovdb_mitsuba/plugin_variants.h -- which of the wheel's variants a
    plugin registers

    Mitsuba's MI_EXPORT_PLUGIN registers (and so compiles) a plugin for every
    variant of the wheel: 13 for mitsuba 3.9.1. A development build can ask
    for fewer (CMake: -DNVDB_VARIANTS="scalar_rgb;llvm_ad_rgb"), which defines
    NVDB_VARIANT_SUBSET and one NVDB_VARIANT_<name> per variant; the plugin
    then registers only those, and its compile time shrinks accordingly.
    Without the option this header changes nothing. Include it last, just
    before MI_EXPORT_PLUGIN.
*/

#pragma once

#include <mitsuba/core/object.h>
#include <mitsuba/core/properties.h>

#if defined(NVDB_VARIANT_SUBSET)

NAMESPACE_BEGIN(mitsuba)
namespace nvdb_detail {
template <template <typename, typename> class Plugin, typename Float, typename Spectrum>
void register_variant(PluginRegisterFn cb, std::string_view name, const char *variant) {
    cb(name, variant, Plugin<Float, Spectrum>::Type,
       [](void *, const Properties &p) -> ref<Object> { return new Plugin<Float, Spectrum>(p); });
}

template <template <typename, typename> class Plugin>
void register_variants(PluginRegisterFn cb, std::string_view name) {
    using LLVM [[maybe_unused]] = dr::DiffArray<JitBackend::LLVM, float>;
    using CUDA [[maybe_unused]] = dr::DiffArray<JitBackend::CUDA, float>;
    (void) cb; (void) name;
#if defined(NVDB_VARIANT_scalar_rgb)
    register_variant<Plugin, float, Color<float, 3>>(cb, name, "scalar_rgb");
#endif
#if defined(NVDB_VARIANT_scalar_spectral)
    register_variant<Plugin, float, Spectrum<float, 4>>(cb, name, "scalar_spectral");
#endif
#if defined(NVDB_VARIANT_scalar_spectral_polarized)
    register_variant<Plugin, float, MuellerMatrix<Spectrum<float, 4>>>(cb, name,
                                                                      "scalar_spectral_polarized");
#endif
#if defined(NVDB_VARIANT_llvm_ad_rgb)
    register_variant<Plugin, LLVM, Color<LLVM, 3>>(cb, name, "llvm_ad_rgb");
#endif
#if defined(NVDB_VARIANT_llvm_ad_mono)
    register_variant<Plugin, LLVM, Color<LLVM, 1>>(cb, name, "llvm_ad_mono");
#endif
#if defined(NVDB_VARIANT_llvm_ad_mono_polarized)
    register_variant<Plugin, LLVM, MuellerMatrix<Color<LLVM, 1>>>(cb, name,
                                                                  "llvm_ad_mono_polarized");
#endif
#if defined(NVDB_VARIANT_llvm_ad_spectral)
    register_variant<Plugin, LLVM, Spectrum<LLVM, 4>>(cb, name, "llvm_ad_spectral");
#endif
#if defined(NVDB_VARIANT_llvm_ad_spectral_polarized)
    register_variant<Plugin, LLVM, MuellerMatrix<Spectrum<LLVM, 4>>>(cb, name,
                                                                     "llvm_ad_spectral_polarized");
#endif
#if defined(NVDB_VARIANT_cuda_ad_rgb)
    register_variant<Plugin, CUDA, Color<CUDA, 3>>(cb, name, "cuda_ad_rgb");
#endif
#if defined(NVDB_VARIANT_cuda_ad_mono)
    register_variant<Plugin, CUDA, Color<CUDA, 1>>(cb, name, "cuda_ad_mono");
#endif
#if defined(NVDB_VARIANT_cuda_ad_mono_polarized)
    register_variant<Plugin, CUDA, MuellerMatrix<Color<CUDA, 1>>>(cb, name,
                                                                  "cuda_ad_mono_polarized");
#endif
#if defined(NVDB_VARIANT_cuda_ad_spectral)
    register_variant<Plugin, CUDA, Spectrum<CUDA, 4>>(cb, name, "cuda_ad_spectral");
#endif
#if defined(NVDB_VARIANT_cuda_ad_spectral_polarized)
    register_variant<Plugin, CUDA, MuellerMatrix<Spectrum<CUDA, 4>>>(cb, name,
                                                                     "cuda_ad_spectral_polarized");
#endif
}
} // namespace nvdb_detail
NAMESPACE_END(mitsuba)

#undef MI_REGISTER_PLUGIN
#define MI_REGISTER_PLUGIN(cb, id, Name) ::mitsuba::nvdb_detail::register_variants<Name>(cb, id)

#endif
