// OpenVDB's chunk readers (io::bloscFromStream, io::unzipFromStream),
// replaced by checked ones in the processes that read .vdb files:
// vdb_chunks.cpp says why and how. An executable that links vdb_chunks.cpp
// exports the two (CMakeLists.txt), and every call libopenvdb makes to
// them comes here.

#pragma once

#include <cstddef>
#include <string>

namespace nanovdb_loader::vdb_reader {

/// The type name of OpenVDB's delayed-load metadata (io::DelayedLoadMetadata)
inline constexpr const char *kDelayedLoadType = "__delayedload";

/**
 * Checks the value of a delayed-load metadata entry (`size` bytes at
 * `value`) as OpenVDB will read it: two arrays of `count` entries, each
 * blosc-compressed or stored, whose sizes must fit the value and whose
 * blosc headers must agree with their bytes. OpenVDB's reader
 * (DelayedLoadMetadata::readValue) trusts both, and hands blosc a buffer
 * without its size. Returns "" for a value OpenVDB reads safely, else what
 * is wrong with it.
 */
std::string delayed_load_damage(const char *value, size_t size);

/// Whether this process's calls to OpenVDB's chunk readers reach the
/// checked ones (false: libopenvdb binds its own, and a damaged chunk is
/// contained by the reader's process only)
bool chunk_readers_replaced();

} // namespace nanovdb_loader::vdb_reader
