// Reading .vdb and .nvdb files. See read.h.

#include "read.h"

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

#include <openvdb/io/Stream.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/NanoToOpenVDB.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>
#include "../../src/loader/vdb_read.h"
#include "../../src/loader/vdb_reader_budget.h"

namespace vdb2nvdb {

namespace fs = std::filesystem;

openvdb::GridPtrVec read_vdb(const std::string &path) {
    std::error_code ec;
    if (!fs::exists(path, ec))
        throw Error(dq(path) + ": no such file");
    if (fs::is_directory(path, ec))
        throw Error(dq(path) + ": is a directory, not a .vdb file");
    // OpenVDB allocates what the file declares: a damaged file asks for
    // gigabytes. Reading runs under the reader's budget (operator new
    // refuses past it, before allocating: src/loader/vdb_reader_budget.h)
    namespace rdr = nanovdb_loader::vdb_reader;
    const uint64_t budget = rdr::memory_budget(fs::file_size(path, ec));
    auto refusal = [&] { return rdr::budget_refusal(dq(path), budget, rdr::heap_refused_bytes()); };
    try {
        rdr::ScopedHeapBudget scoped(budget);
        // Counts OpenVDB would loop over unchecked (a root declaring 4e9
        // tiles): checked against the file first (src/loader/vdb_read.h)
        try {
            nanovdb_loader::check_vdb_structure(path);
        } catch (const nanovdb_loader::Error &e) {
            throw Error(e.what());
        }
        // io::Stream reads the grids in file order (io::File::getGrids()
        // returns them sorted by name).
        std::ifstream is(path, std::ios::binary);
        if (!is)
            throw Error(dq(path) + ": cannot open: " + std::strerror(errno));
        openvdb::io::Stream stream(is, /*delayLoad=*/false);
        openvdb::GridPtrVecPtr grids = stream.getGrids();
        if (!grids)
            throw Error(dq(path) + ": cannot read as an OpenVDB file: no grids read");
        // OpenVDB reads a grid cut off by the end of the file as short
        // buffers without a word; the stream knows
        if (!is)
            throw Error(dq(path) + ": truncated or corrupt: its grids run past the end of "
                        "the file");
        return *grids;
    } catch (const Error &) {
        throw;
    } catch (const openvdb::Exception &e) {
        if (rdr::heap_refused_bytes())
            throw Error(refusal());
        throw Error(dq(path) + ": cannot read as an OpenVDB file: " + e.what());
    } catch (const std::bad_alloc &) {
        throw Error(refusal());
    } catch (const std::exception &e) {
        if (rdr::heap_refused_bytes())
            throw Error(refusal());
        throw Error(dq(path) + ": cannot read as an OpenVDB file (corrupt or truncated?): " +
                    e.what());
    }
}

namespace {

/// A NanoVDB grid back into OpenVDB, for the types vdb2nvdb converts or
/// lists with values: float (and its quantized forms, Fp4/8/16/N, which
/// come back as float) and Vec3f. NanoVDB's own dispatch over all 14 types
/// it can convert made this file cost 110 s of a first build instead of 28
/// s; the others (double, integers, masks, Vec3d, Vec4) are skipped with a
/// note, as the types NanoVDB cannot convert are.
openvdb::GridBase::Ptr to_openvdb(const nanovdb::GridHandle<nanovdb::HostBuffer> &h) {
    if (const auto *g = h.grid<float>())
        return nanovdb::nanoToOpenVDB(*g);
    if (const auto *g = h.grid<nanovdb::Fp4>())
        return nanovdb::nanoToOpenVDB(*g);
    if (const auto *g = h.grid<nanovdb::Fp8>())
        return nanovdb::nanoToOpenVDB(*g);
    if (const auto *g = h.grid<nanovdb::Fp16>())
        return nanovdb::nanoToOpenVDB(*g);
    if (const auto *g = h.grid<nanovdb::FpN>())
        return nanovdb::nanoToOpenVDB(*g);
    if (const auto *g = h.grid<nanovdb::Vec3f>())
        return nanovdb::nanoToOpenVDB(*g);
    throw std::runtime_error("vdb2nvdb reads back float, Fp4/8/16/N and Vec3f grids only");
}

} // namespace

openvdb::GridPtrVec read_nvdb(const std::string &path) {
    std::error_code ec;
    if (!fs::exists(path, ec))
        throw Error(dq(path) + ": no such file");
    std::vector<nanovdb::GridHandle<nanovdb::HostBuffer>> handles;
    try {
        handles = nanovdb::io::readGrids<nanovdb::HostBuffer>(path);
    } catch (const std::exception &e) {
        throw Error(dq(path) + ": cannot read as a NanoVDB file (NanoVDB " +
                    std::to_string(NANOVDB_MAJOR_VERSION_NUMBER) + "." +
                    std::to_string(NANOVDB_MINOR_VERSION_NUMBER) + "'s reader): " + e.what());
    }
    openvdb::GridPtrVec grids;
    for (size_t i = 0; i < handles.size(); ++i) {
        const nanovdb::GridMetaData *m = handles[i].gridMetaData();
        const std::string name = m ? m->shortGridName() : std::to_string(i);
        try {
            grids.push_back(to_openvdb(handles[i]));
        } catch (const std::exception &e) {
            std::string type = m ? nanovdb::toStr(m->gridType()) : "?";
            if (type == "End") // a type newer than this NanoVDB (OnIndex, ...)
                type = "grid type " + std::to_string(uint32_t(m->gridType()));
            note(dq(path) + ": grid " + dq(name) + " (" + type + "): not read: " + e.what());
        }
    }
    if (grids.empty())
        throw Error(dq(path) + ": no grid that vdb2nvdb reads back (float, Fp4/8/16/N, Vec3f)");
    return grids;
}

openvdb::GridPtrVec read_input(const std::string &path) {
    const bool nvdb = path.size() >= 5 && path.compare(path.size() - 5, 5, ".nvdb") == 0;
    return nvdb ? read_nvdb(path) : read_vdb(path);
}
} // namespace vdb2nvdb
