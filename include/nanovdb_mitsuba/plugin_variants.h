/*
    nanovdb_mitsuba/plugin_variants.h -- which of Mitsuba's variants a
    plugin registers, and in which of its files

    Mitsuba's MI_EXPORT_PLUGIN registers (and so compiles) a plugin for every
    variant Mitsuba was built with (the wheel's 13, or a checkout's
    mitsuba.conf), in one file. Two options, both set by CMake, change that;
    without them this header changes nothing:

    * NVDB_PLUGIN_PART=1, 2 or 3: this file is the plugin's part for one
      backend (scalar, LLVM, CUDA). It compiles and registers that backend's
      variants only, and MI_EXPORT_PLUGIN defines nvdb_register_part_<N>()
      instead of the plugin's entry point; src/plugin_entry.cpp defines the
      entry point, init_plugin(), which calls the parts the build has. CMake
      compiles each plugin's source once per backend (CMakeLists.txt,
      nvdb_plugin_sources): the JIT backends' parts only trace kernels,
      which Dr.Jit compiles with its own optimizer, so they build at -O1,
      and the parts build in parallel (bench/PERF_LOG.md 29).
    * NVDB_VARIANT_LIST=",scalar_rgb,llvm_ad_rgb,": a development build
      (CMake: -DNVDB_VARIANTS="scalar_rgb;llvm_ad_rgb") registers and
      compiles only these variants.

    Both go through Mitsuba's own list (MI_REGISTER_PLUGIN): a variant left
    out is registered by no one and its class is never instantiated (the
    list names a stand-in, Skipped, in its place).

    Include it among the plugin's includes, before MI_EXPORT_PLUGIN.
*/

#pragma once

#include <mitsuba/core/object.h>
#include <mitsuba/core/properties.h>

#include <string_view>
#include <type_traits>

#if defined(NVDB_VARIANT_LIST) || defined(NVDB_PLUGIN_PART)

NAMESPACE_BEGIN(mitsuba)
namespace nvdb_detail {
// Internal linkage: each part has its own wanted() (one definition per
// part, where a shared name would be one definition for all of them)
namespace {

/// Whether this file registers the variant named `variant`
constexpr bool wanted(std::string_view variant) {
#if defined(NVDB_PLUGIN_PART)
    // the part's backend, by the variant's name: scalar_*, llvm_*, cuda_*
    constexpr std::string_view prefixes[] = { "scalar_", "llvm_", "cuda_" };
    if (variant.substr(0, prefixes[NVDB_PLUGIN_PART - 1].size()) !=
        prefixes[NVDB_PLUGIN_PART - 1])
        return false;
#endif
#if defined(NVDB_VARIANT_LIST)
    // ",a,b," holds ",variant,"
    constexpr std::string_view list = NVDB_VARIANT_LIST;
    bool listed = false;
    for (size_t i = 0; i + variant.size() + 2 <= list.size(); ++i)
        if (list[i] == ',' && list.substr(i + 1, variant.size()) == variant &&
            list[i + 1 + variant.size()] == ',')
            listed = true;
    if (!listed)
        return false;
#endif
    return true;
}

/// What Mitsuba's list names in place of a variant left out (never
/// registered, never constructed)
template <typename Float, typename Spectrum> struct Skipped : Object {
    static constexpr ObjectType Type = ObjectType::Unknown;
    Skipped(const Properties &) { }
};

/// Plugin<Float, Spectrum> where the variant is wanted, else Skipped
template <template <typename, typename> class Plugin> struct Parts {
    template <typename Float, typename Spectrum>
    using Part = std::conditional_t<wanted(detail::variant<Float, Spectrum>::name),
                                    Plugin<Float, Spectrum>, Skipped<Float, Spectrum>>;
};

} // namespace
} // namespace nvdb_detail
NAMESPACE_END(mitsuba)

/// Mitsuba's registration, with the variants left out skipped
#define NVDB_REGISTER_WANTED(fn, name, Name)                                                 \
    auto nvdb_register = [fn](std::string_view id, std::string_view variant, ObjectType type, \
                              PluginInstantiateFn make) {                                    \
        if (::mitsuba::nvdb_detail::wanted(variant))                                         \
            fn(id, variant, type, make);                                                     \
    };                                                                                       \
    MI_REGISTER_PLUGIN(nvdb_register, name, ::mitsuba::nvdb_detail::Parts<Name>::template Part)

#undef MI_EXPORT_PLUGIN
#if defined(NVDB_PLUGIN_PART)
// A part: its registration, called by src/plugin_entry.cpp's init_plugin()
#  define NVDB_PART_FN_(n) nvdb_register_part_##n
#  define NVDB_PART_FN(n) NVDB_PART_FN_(n)
#  define MI_EXPORT_PLUGIN(Name)                                                            \
    void NVDB_PART_FN(NVDB_PLUGIN_PART)(std::string_view name, PluginRegisterFn fn) {     \
        NVDB_REGISTER_WANTED(fn, name, Name);                                              \
    }
#else
#  define MI_EXPORT_PLUGIN(Name)                                                            \
    extern "C" MI_EXPORT void init_plugin(std::string_view name, PluginRegisterFn fn) {    \
        NVDB_REGISTER_WANTED(fn, name, Name);                                              \
    }
#endif

#endif
