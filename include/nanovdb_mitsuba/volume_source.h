/*
    nanovdb_mitsuba/volume_source.h -- where a volume's grid came from, for
    other plugins' error messages

    A plugin that holds volumes (the emissive medium) names the file and the
    grid when it refuses one; nanovdbvolume implements this, found by
    dynamic_cast (other volumes are named by their class).
*/

#pragma once

#include <cstdint>
#include <string>

namespace nanovdb_mitsuba {

class VolumeSource {
public:
    virtual ~VolumeSource() = default;
    /// "\"<file>\" grid \"<name>\"" (or the memory source's label)
    virtual std::string source_name() const = 0;
    /// NanoVDB's GridClass code (0 unknown, 1 level set, 2 fog volume, ...)
    virtual uint32_t grid_class_code() const = 0;
};

} // namespace nanovdb_mitsuba
