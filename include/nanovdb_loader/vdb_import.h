// nanovdb_loader/vdb_import.h -- an OpenVDB .vdb file's grid as NanoVDB bytes,
// in memory, for nanovdbvolume's `filename` (no .nvdb file is written)
//
// The file is read in a separate process, nanovdb-vdb-reader, under a
// memory budget and a deadline (src/loader/vdb_import.cpp says why): a
// damaged file that crashes OpenVDB's reader, or asks it for gigabytes,
// becomes an Error here that says the file is damaged. The caller's
// process is never at risk. The grid bytes that come back are not
// trusted: the caller validates them as any .nvdb grid.
//
// Only the grid asked for is read (its metadata first, to choose it, then
// that grid alone) and converted with vdb2nvdb's rules (src/convert/
// prepare.cpp, to_nano.cpp): a float grid as float, a level set first made
// a fog volume (openvdb::tools::sdfToFogVolume), a vec3s grid as Vec3f.
// Other types (points, integers, doubles, ...) are refused. Built only with
// OpenVDB (Debian's libopenvdb-dev); without it vdb_import_available() is
// false and import_vdb_grid() throws a message that says how to get it.
// Every failure throws nanovdb_loader::Error whose message starts with
// "\"<path>\": ".
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <nanovdb_loader/container.h>

namespace nanovdb_loader {

/// A grid of a .vdb file, converted
struct VdbGrid {
    std::shared_ptr<const uint8_t> data; ///< one NanoVDB grid buffer (what a .nvdb
    size_t size = 0;                     ///< segment holds), and its bytes
    std::string name;           ///< the grid's name
    uint32_t index = 0;         ///< its position in the file
    uint32_t source_class = 0;  ///< OpenVDB's GridClass (0 unknown, 1 level set, 2 fog, 3 staggered)
    bool fogged = false;        ///< a level set made a fog volume
    double read_seconds = 0, convert_seconds = 0; ///< inside the reader
    double reader_seconds = 0;     ///< the reader process, start to reply
    uint64_t reader_peak_bytes = 0; ///< its peak resident memory
};

/// A grid of a .vdb file as its descriptor and metadata describe it
struct VdbGridInfo {
    std::string name;         ///< made printable (printable_text)
    std::string type;         ///< OpenVDB's value type: "float", "vec3s", "int32", ...
    uint32_t grid_class = 0;  ///< OpenVDB's GridClass (0 unknown, 1 level set, 2 fog, 3 staggered)
};

/// Whether the plugin was built with OpenVDB (.vdb files can be read)
bool vdb_import_available();

/// Whether `path` names an OpenVDB file (its extension is .vdb, any case)
bool is_vdb_path(const std::string &path);

/// The grid `selector` of the .vdb file at `path`: a name, else a decimal
/// index, or (empty) the first float or vec3s grid; converted (a level set
/// made a fog volume unless fog_level_sets is false).
VdbGrid import_vdb_grid(const std::string &path, const std::string &selector,
                        bool fog_level_sets = true);

/// Grid `index` of the NanoVDB file at `path`, a level set, made a fog
/// volume as vdb2nvdb makes one (in the reader process: the conversion
/// needs OpenVDB). `name` is the grid's name as the caller's listing has
/// it: a reply for another grid is refused.
VdbGrid import_nvdb_level_set_as_fog(const std::string &path, uint32_t index,
                                     const std::string &name);

/// Every grid of the .vdb file at `path` (names, types, classes; no voxels),
/// read by the reader process: a damaged file is an Error, never a crash.
std::vector<VdbGridInfo> list_vdb_grids(const std::string &path);

} // namespace nanovdb_loader
