// nanovdb_grid_list: the grids of a .nvdb or .vdb file, for the Python
// package (nanovdb_mitsuba/files.py), as JSON through one C function.
//
// Why a C function loaded with ctypes and not a nanobind extension: the
// wheel is tagged py3 (pyproject.toml: wheel.py-api; the plugins do not
// link libpython), and nanobind's stable-ABI builds need Python 3.12, so an
// extension module would tie the wheel to one CPython version (3.11 here).
// A C ABI keeps it py3, and JSON keeps the answer structured: the names,
// types and classes arrive as fields, never as text to parse.
//
// .nvdb: the loader's headers (nanovdb_loader::list_grids: segment headers
// and grid metadata, no payload). .vdb: the reader process's listing
// (nanovdb_loader::list_vdb_grids), so that a damaged file is an error,
// never a crash of the caller.

#include <nanovdb_loader/container.h>
#include <nanovdb_loader/vdb_import.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

namespace nl = nanovdb_loader;

/// A JSON string literal of (printable, valid UTF-8) text
std::string quoted(const std::string &text) {
    std::string out = "\"";
    for (unsigned char c : nl::printable_text(text)) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += char(c);
        } else if (c < 0x20) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\u%04x", c);
            out += buf;
        } else {
            out += char(c);
        }
    }
    return out + "\"";
}

/// The type as the package compares it: OpenVDB's value-type names, which
/// vdb2nvdb uses too. A one-channel float grid that nanovdbvolume reads
/// (float, Half, Fp4, Fp8, Fp16, FpN) is "float", a Vec3f grid "vec3s";
/// others keep NanoVDB's name.
std::string package_type(uint32_t grid_type) {
    const std::string name = nl::grid_type_name(grid_type);
    for (const char *f : { "float", "Half", "Fp4", "Fp8", "Fp16", "FpN" })
        if (name == f)
            return "float";
    return name == "Vec3f" ? "vec3s" : name;
}

std::string entry(size_t index, const std::string &name, const std::string &type,
                  const std::string &stored_type, uint32_t grid_class) {
    return "{\"index\": " + std::to_string(index) + ", \"name\": " + quoted(name) +
           ", \"type\": " + quoted(type) + ", \"stored_type\": " + quoted(stored_type) +
           ", \"class\": " + quoted(nl::grid_class_name(grid_class)) + "}";
}

std::string listing(const std::string &path) {
    std::string grids;
    if (nl::is_vdb_path(path)) {
        std::vector<nl::VdbGridInfo> all = nl::list_vdb_grids(path);
        for (size_t i = 0; i < all.size(); ++i)
            // (OpenVDB's GridClass codes 0-3 are NanoVDB's too)
            grids += (i ? ", " : "") + entry(i, all[i].name, all[i].type, all[i].type,
                                             all[i].grid_class);
    } else {
        std::vector<nl::GridEntry> all = nl::list_grids(path);
        for (size_t i = 0; i < all.size(); ++i)
            grids += (i ? ", " : "") + entry(i, all[i].name, package_type(all[i].grid_type),
                                             nl::grid_type_name(all[i].grid_type),
                                             all[i].grid_class);
    }
    return "{\"grids\": [" + grids + "]}";
}

char *copy(const std::string &s) {
    char *out = (char *) std::malloc(s.size() + 1);
    if (out)
        std::memcpy(out, s.c_str(), s.size() + 1);
    return out;
}

} // namespace

extern "C" {

/// {"grids": [{"index", "name", "type", "stored_type", "class"}, ...]} of the
/// file at `path`, or {"error": message}, the message naming the file.
/// Free the result with nvdb_grid_list_free.
__attribute__((visibility("default"))) char *nvdb_grid_list_json(const char *path) {
    try {
        return copy(listing(path ? path : ""));
    } catch (const std::exception &e) {
        return copy("{\"error\": " + quoted(e.what()) + "}");
    } catch (...) {
        return copy("{\"error\": " + quoted("\"" + std::string(path ? path : "") +
                                            "\": cannot list its grids") + "}");
    }
}

__attribute__((visibility("default"))) void nvdb_grid_list_free(char *json) { std::free(json); }

} // extern "C"
