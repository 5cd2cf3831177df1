// The entry point of a plugin built in parts, one per backend
// (nanovdb_mitsuba/plugin_variants.h): Mitsuba's plugin manager calls
// init_plugin(), which registers the variants of each part the build has
// (CMakeLists.txt defines NVDB_PLUGIN_HAS_PART_<N> for them).
#include <mitsuba/core/object.h>

#include <string_view>

NAMESPACE_BEGIN(mitsuba)
void nvdb_register_part_1(std::string_view name, PluginRegisterFn fn);  // scalar
void nvdb_register_part_2(std::string_view name, PluginRegisterFn fn);  // LLVM
void nvdb_register_part_3(std::string_view name, PluginRegisterFn fn);  // CUDA
NAMESPACE_END(mitsuba)

extern "C" MI_EXPORT void init_plugin(std::string_view name, mitsuba::PluginRegisterFn fn) {
#if defined(NVDB_PLUGIN_HAS_PART_1)
    mitsuba::nvdb_register_part_1(name, fn);
#endif
#if defined(NVDB_PLUGIN_HAS_PART_2)
    mitsuba::nvdb_register_part_2(name, fn);
#endif
#if defined(NVDB_PLUGIN_HAS_PART_3)
    mitsuba::nvdb_register_part_3(name, fn);
#endif
    (void) name;
    (void) fn;
}
