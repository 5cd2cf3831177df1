// An OpenVDB file's grid as NanoVDB bytes, read and converted in this
// process (src/loader/vdb_read.h). Only nanovdb-vdb-reader
// (src/loader/vdb_reader_main.cpp) and the fuzzer (tests/fuzz/fuzz_vdb.cpp)
// run it: OpenVDB trusts its stream, so nanovdbvolume reads a .vdb through
// that separate process (src/loader/vdb_import.cpp says why).
// The conversion is vdb2nvdb's own (src/convert/: prepare.cpp, to_nano.cpp),
// the nanovdb_convert library, which vdb2nvdb links too, so the plugin and
// the converter cannot drift apart.

#include "vdb_read.h"
#include "vdb_chunks.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include <openvdb/io/Archive.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/openvdb.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/NanoToOpenVDB.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>
#include <nanovdb_convert/prepare.h>
#include <nanovdb_convert/to_nano.h>

namespace nanovdb_loader {

namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

double since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

/// Whether a grid of this type converts (float, vec3s)
bool convertible(const openvdb::GridBase &g) {
    return g.isType<openvdb::FloatGrid>() || g.isType<openvdb::Vec3SGrid>();
}

/**
 * The length-prefixed fields of a .vdb header, checked against the bytes
 * left before OpenVDB reads them. OpenVDB's readString and Metadata::read
 * allocate and zero-fill what a length says: a damaged length of 4e9
 * allocates up to the reader's budget before the read fails, in a second or
 * so, and the message is OpenVDB's (or the budget's). Only lengths and
 * counts are read here, every field is skipped, and the stream is put back
 * where it was; OpenVDB then reads the same bytes. Fields (OpenVDB 10,
 * io/io.h, Metadata.h, MetaMap.cc, GridDescriptor.cc):
 *   string     uint32 length, then its bytes
 *   metadata   uint32 count, then per entry: name (string), type name
 *              (string), value (uint32 size, then its bytes)
 *   descriptor unique name, grid type, (file version >= 216) instance
 *              parent: three strings; then three int64 offsets
 * A valid file's fields always fit, so a refusal here is damage.
 */
class LengthCheck {
public:
    /// The bytes the fields must fit in: the rest of the file, or of a grid
    enum class Within { File, Grid };

    /// `end`: the byte the fields must end by (the file's or the grid's
    /// end, `within`); `what`: the error's subject
    LengthCheck(std::istream &is, int64_t end, Within within, const std::string &label,
                std::string what)
        : m_is(is), m_start(is.tellg()), m_end(end), m_within(within), m_label(label),
          m_what(std::move(what)) {}
    ~LengthCheck() {
        m_is.clear();
        m_is.seekg(m_start);
    }
    LengthCheck(const LengthCheck &) = delete;
    LengthCheck &operator=(const LengthCheck &) = delete;

    /// A length-prefixed field: a string, or a metadata value
    void field(const char *name) { skip(length(name), name); }

    /// The size at which OpenVDB reads a value of this metadata type,
    /// whatever the value's size field says (none: it reads that many bytes)
    static std::optional<uint64_t> fixed_size(const std::string &type) {
        if (type.empty() || type == openvdb::StringMetadata::staticTypeName() ||
            !openvdb::Metadata::isRegisteredType(type))
            return std::nullopt;
        return openvdb::Metadata::createMetadata(type)->size();
    }

    /// A length-prefixed string, read (one of up to 256 bytes; a longer
    /// one is skipped and reads as "")
    std::string text(const char *name) {
        const uint64_t n = length(name);
        if (n > 256) {
            skip(n, name);
            return "";
        }
        std::vector<char> s = bytes(n, name);
        return std::string(s.begin(), s.end());
    }

    /// The next n bytes, which must be there
    std::vector<char> bytes(uint64_t n, const char *name) {
        if (n > left())
            fail(name, n);
        std::vector<char> out(n);
        m_is.read(out.data(), std::streamsize(n));
        return out;
    }

    void metadata() {
        const uint64_t count = length("metadata count");
        // each entry takes at least its three 4-byte lengths
        if (count * 12 > left())
            fail("metadata count", count * 12);
        for (uint64_t i = 0; i < count; ++i) {
            field("metadata name");
            const std::string type = text("metadata type name");
            const uint64_t n = length("metadata value");
            if (type == vdb_reader::kDelayedLoadType) {
                // Delayed-load values hold blosc buffers that OpenVDB
                // trusts (vdb_chunks.h): read and checked here
                const std::vector<char> value = bytes(n, "metadata value");
                const std::string bad = vdb_reader::delayed_load_damage(value.data(), value.size());
                if (!bad.empty())
                    throw Error(m_label + ": damaged: " + m_what + ": " + bad);
                continue;
            }
            // The bytes OpenVDB's reader takes, so that the next entry is
            // checked where OpenVDB reads it: a value of a fixed-size type
            // (bool, vec3i, mat4d, ...) is read at its type's size, whatever
            // its size field says (TypedMetadata::readValue); a string or a
            // type OpenVDB does not know is read at its size field's
            skip(fixed_size(type).value_or(n), "metadata value");
        }
    }

    void descriptor(uint32_t file_version) {
        field("grid name");
        field("grid type");
        if (file_version >= openvdb::OPENVDB_FILE_VERSION_GRID_INSTANCING)
            field("instance parent name");
        skip(24, "grid offsets");
    }

private:
    uint64_t left() const {
        const int64_t pos = m_is.tellg();
        return pos < 0 || pos > m_end ? 0 : uint64_t(m_end - pos);
    }

    uint64_t length(const char *name) {
        uint32_t n = 0;
        m_is.read(reinterpret_cast<char *>(&n), 4);
        if (!m_is)
            fail(name, 4);
        return n;
    }

    void skip(uint64_t n, const char *name) {
        if (n > left())
            fail(name, n);
        m_is.seekg(std::streamoff(n), std::ios::cur);
    }

    [[noreturn]] void fail(const char *name, uint64_t need) const {
        throw Error(m_label + ": damaged: " + m_what + ": its " + name + " needs " +
                    std::to_string(need) + " bytes, and " + std::to_string(left()) +
                    " are left" + (m_within == Within::Grid ? " in the grid" : " in the file"));
    }

    std::istream &m_is;
    std::streampos m_start;
    int64_t m_end;
    Within m_within;
    const std::string &m_label;
    std::string m_what;
};

/**
 * A .vdb file read as openvdb::io::File reads one grid (the header, the
 * grid descriptors, then one grid by its offsets), with the checks File
 * leaves out: every descriptor's offsets lie inside the file, and the grid's
 * read ends inside its own bytes with the stream intact. (File reads a grid
 * cut off by a truncated file as short buffers, silently.) Archive's
 * protected steps do the reading; nothing of the format is parsed here.
 */
class CheckedVdbFile final : public openvdb::io::Archive {
public:
    struct Grid {
        openvdb::io::GridDescriptor descriptor;
        openvdb::GridBase::Ptr grid; ///< its metadata only, until read()
    };

    /// Throws NoOffsets for a stream without grid offsets (io::Stream's)
    struct NoOffsets {};

    CheckedVdbFile(const std::string &path, const std::string &label)
        : m_label(label), m_is(path, std::ios::binary) {
        if (!m_is)
            throw Error(label + ": cannot open: " + std::strerror(errno));
        m_size = (int64_t) fs::file_size(path);
        readHeader(m_is);
        // Tagged as io::File tags its stream (the grids' readers expect it)
        m_meta = std::make_shared<openvdb::io::StreamMetadata>();
        m_meta->setSeekable(true);
        openvdb::io::setStreamMetadataPtr(m_is, m_meta, /*transfer=*/false);
        setFormatVersion(m_is);
        setLibraryVersion(m_is);
        setDataCompression(m_is);
        // (readHeader parses the UUID with operator>>: a damaged one fails
        // the stream instead of throwing)
        if (!m_is)
            throw Error(label + ": damaged: its header cannot be read (a corrupt version, "
                                "flag or UUID field)");
        openvdb::MetaMap file_meta;
        LengthCheck(m_is, m_size, LengthCheck::Within::File, label, "the file's metadata")
            .metadata();
        file_meta.readMeta(m_is);
        if (!inputHasGridOffsets())
            throw NoOffsets{};
        int32_t count = readGridCount(m_is);
        if (!m_is || count < 0 || count > (1 << 20))
            throw Error(label + ": cannot read as an OpenVDB file: bad grid count");
        for (int32_t i = 0; i < count; ++i) {
            Grid g;
            LengthCheck(m_is, m_size, LengthCheck::Within::File, label,
                        "the descriptor of grid " + std::to_string(i))
                .descriptor(openvdb::io::getFormatVersion(m_is));
            g.grid = g.descriptor.read(m_is);
            const openvdb::io::GridDescriptor &d = g.descriptor;
            if (!m_is || !(0 < d.getGridPos() && d.getGridPos() <= d.getBlockPos() &&
                           d.getBlockPos() <= d.getEndPos()))
                throw Error(label + ": cannot read as an OpenVDB file: grid " +
                            std::to_string(i) + "'s offsets are invalid");
            if (d.getEndPos() > m_size)
                throw Error(label + ": truncated: grid \"" + d.gridName() + "\" ends at byte " +
                            std::to_string(d.getEndPos()) + ", the file has " +
                            std::to_string(m_size));
            // Its metadata (name, class), as File::readAllGridMetadata
            d.seekToGrid(m_is);
            readGridCompression(m_is);
            LengthCheck(m_is, d.getEndPos(), LengthCheck::Within::Grid, label,
                        "grid \"" + d.gridName() + "\"'s metadata")
                .metadata();
            g.grid->readMeta(m_is);
            g.grid->setName(d.gridName());
            if (!m_is)
                throw Error(label + ": cannot read as an OpenVDB file: grid \"" + d.gridName() +
                            "\"'s metadata");
            d.seekToEnd(m_is);
            m_grids.push_back(std::move(g));
        }
    }

    /// Every grid's root counts against its bytes (check_root_counts)
    void check_all_roots() {
        for (const Grid &g : m_grids)
            check_root_counts(g.descriptor);
    }

    openvdb::GridPtrVec metadata() const {
        openvdb::GridPtrVec out;
        for (const Grid &g : m_grids)
            out.push_back(g.grid);
        return out;
    }

    /// Grid i, whole (an instance: its parent's tree, as File reads it)
    openvdb::GridBase::Ptr read(size_t i) {
        const openvdb::io::GridDescriptor &d = m_grids[i].descriptor;
        openvdb::GridBase::Ptr grid = read_one(d);
        if (d.isInstance()) {
            size_t parent = m_grids.size();
            for (size_t k = 0; k < m_grids.size(); ++k)
                if (m_grids[k].descriptor.uniqueName() == d.instanceParentName())
                    parent = k;
            if (parent == m_grids.size())
                throw Error(m_label + ": grid \"" + d.gridName() + "\" is an instance of \"" +
                            d.instanceParentName() + "\", which the file does not hold");
            grid->setTree(read_one(m_grids[parent].descriptor)->baseTreePtr());
        }
        return grid;
    }

private:
    /**
     * The counts at the top of a grid's tree, checked against the bytes the
     * grid spans before OpenVDB reads them. RootNode::readTopology loops
     * over the tile and child counts it reads, inserting or allocating for
     * each, without a check: a damaged count of 4e9 tiles would loop for
     * minutes, and one of 4e9 children allocates 270 KB each. Each tile
     * takes at least its origin, value and active flag in the file, and
     * each child its origin and two 4096-byte masks, so counts that need
     * more bytes than the grid has are damage, refused here; so is a tile
     * whose active flag is neither 0 nor 1.
     */
    void check_root_counts(const openvdb::io::GridDescriptor &d) {
        const uint32_t version = openvdb::io::getFormatVersion(m_is);
        if (version < openvdb::OPENVDB_FILE_VERSION_GRID_INSTANCING || d.isInstance())
            return; // (the topology comes after the transform from 216 on)
        d.seekToGrid(m_is);
        readGridCompression(m_is);
        openvdb::GridBase::Ptr probe = openvdb::GridBase::createGrid(d.gridType());
        probe->readMeta(m_is);
        probe->readTransform(m_is);
        const uint64_t value_bytes = probe->isType<openvdb::Vec3SGrid>() ? 12 : 4;
        int32_t buffer_count = 0;
        uint32_t tiles = 0, children = 0;
        std::vector<char> background(value_bytes);
        m_is.read(reinterpret_cast<char *>(&buffer_count), 4);
        m_is.read(background.data(), std::streamsize(value_bytes));
        m_is.read(reinterpret_cast<char *>(&tiles), 4);
        m_is.read(reinterpret_cast<char *>(&children), 4);
        if (!m_is)
            throw Error(m_label + ": damaged: grid \"" + d.gridName() +
                        "\" ends inside its header");
        const int64_t left = d.getEndPos() - int64_t(m_is.tellg());
        const uint64_t need = uint64_t(tiles) * (12 + value_bytes + 1) +
                              uint64_t(children) * (12 + 2 * 4096);
        if (left < 0 || need > uint64_t(left))
            throw Error(m_label + ": damaged: grid \"" + d.gridName() + "\"'s root declares " +
                        std::to_string(tiles) + " tiles and " + std::to_string(children) +
                        " child nodes, which need at least " + std::to_string(need) +
                        " bytes; the grid has " + std::to_string(std::max<int64_t>(left, 0)));
        // The tiles follow: origin, value and an active flag each, which
        // RootNode::readTopology reads into a bool byte for byte (a flag of
        // 45 is then undefined behaviour wherever the tile is tested)
        const uint64_t tile_bytes = 12 + value_bytes + 1;
        std::vector<char> records(size_t(tiles) * tile_bytes);
        m_is.read(records.data(), std::streamsize(records.size()));
        for (uint32_t t = 0; t < tiles; ++t) {
            const unsigned char active = (unsigned char) records[t * tile_bytes + tile_bytes - 1];
            if (active > 1)
                throw Error(m_label + ": damaged: grid \"" + d.gridName() + "\"'s root tile " +
                            std::to_string(t) + " (of " + std::to_string(tiles) +
                            ") has an active flag of " + std::to_string(active) +
                            ", where 0 or 1 is valid");
        }
    }

    openvdb::GridBase::Ptr read_one(const openvdb::io::GridDescriptor &d) {
        check_root_counts(d);
        openvdb::GridBase::Ptr grid = openvdb::GridBase::createGrid(d.gridType());
        grid->setSaveFloatAsHalf(d.saveFloatAsHalf());
        d.seekToGrid(m_is);
        Archive::readGrid(grid, d, m_is);
        if (!m_is || (int64_t) m_is.tellg() > d.getEndPos())
            throw Error(m_label + ": grid \"" + d.gridName() + "\" is corrupt or truncated: "
                        "its data runs past its end in the file");
        return grid;
    }

    std::string m_label;
    std::ifstream m_is;
    openvdb::io::StreamMetadata::Ptr m_meta;
    int64_t m_size = 0;
    std::vector<Grid> m_grids;
};

/// The grid `selector` names among `meta` (metadata only): vdb2nvdb's and
/// the .nvdb files' rule, a name first, then an index, "" the first
/// convertible grid
size_t choose(const std::string &label, const openvdb::GridPtrVec &meta,
              const std::string &selector) {
    if (selector.empty()) {
        for (size_t i = 0; i < meta.size(); ++i)
            if (convertible(*meta[i]))
                return i;
        throw Error(label + ": no float or vec3s grid; the file holds: " +
                    vdb2nvdb::list_grids(meta));
    }
    for (size_t i = 0; i < meta.size(); ++i)
        if (meta[i]->getName() == selector)
            return i;
    if (std::all_of(selector.begin(), selector.end(),
                    [](unsigned char c) { return std::isdigit(c); }) && selector.size() < 10) {
        size_t i = std::stoull(selector);
        if (i < meta.size())
            return i;
    }
    throw Error(label + ": no grid named \"" + selector + "\"; the file holds: " +
                vdb2nvdb::list_grids(meta));
}

} // namespace

namespace {

/// `grid` (read whole) converted as vdb2nvdb converts it: its preparation
/// (a level set made a fog volume unless fog_level_sets is false) and
/// OpenToNanoVDB, into `out`
void convert_into(openvdb::GridBase::Ptr grid, const std::string &label, bool fog_level_sets,
                  VdbGrid &out) {
    const auto t0 = Clock::now();
    const std::string name = grid->getName();
    try {
        vdb2nvdb::Handle h;
        { // (the OpenVDB grid is freed at the end of this scope, before the copy)
            openvdb::GridPtrVec one{ std::move(grid) };
            vdb2nvdb::Options opts;
            opts.grids = { name };
            opts.keep_level_sets = !fog_level_sets;
            std::vector<vdb2nvdb::Prepared> prepared =
                vdb2nvdb::select_and_prepare(one, label, opts);
            const vdb2nvdb::Prepared &p = prepared.front();
            out.name = p.name;
            out.source_class = uint32_t(p.source_class);
            out.fogged = p.fogged;
            h = p.grid ? vdb2nvdb::convert_one(*p.grid, vdb2nvdb::Quantize::Float, opts)
                       : vdb2nvdb::convert_vec3(*p.vec);
        }
        // The handle itself is kept (no copy): the plugin copies it once,
        // into the block its backend owns
        out.size = h.size();
        auto owner = std::make_shared<vdb2nvdb::Handle>(std::move(h));
        out.data = std::shared_ptr<const uint8_t>(owner, owner->data());
    } catch (const vdb2nvdb::Error &e) {
        // select_and_prepare's messages start with the label, convert_one's
        // with the grid (a fuzzed file: 'grid "density": NanoVDB conversion
        // failed: ... nearly singular matrix' named no file)
        const std::string what = e.what();
        throw Error(what.rfind(label, 0) == 0 ? what : label + ": " + what);
    } catch (const std::exception &e) {
        throw Error(label + ": cannot convert grid \"" + name + "\": " + e.what());
    }
    out.convert_seconds = since(t0);
}

/// The file opened with its checks, for read_vdb_grid and read_vdb_listing
CheckedVdbFile &open_checked(std::optional<CheckedVdbFile> &opened, const std::string &path,
                             const std::string &label) {
    try {
        opened.emplace(path, label);
    } catch (const CheckedVdbFile::NoOffsets &) {
        throw Error(label + ": an OpenVDB stream without grid offsets (written by "
                    "io::Stream): convert it with vdb2nvdb");
    }
    return *opened;
}

void initialize_openvdb() {
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

/// Every reading entry point's start: OpenVDB initialized once, and the
/// file's label ("path", as errors quote it) once the path is a regular file
std::string opened_label(const std::string &path) {
    initialize_openvdb();
    const std::string label = "\"" + path + "\"";
    std::error_code ec;
    if (!fs::is_regular_file(path, ec))
        throw Error(label + (fs::exists(path, ec) ? ": not a regular file" : ": no such file"));
    return label;
}

} // namespace

VdbGrid read_vdb_grid(const std::string &path, const std::string &selector,
                      bool fog_level_sets) {
    const std::string label = opened_label(path);
    VdbGrid out;
    auto t0 = Clock::now();
    openvdb::GridBase::Ptr grid;
    try {
        // The grids' metadata (no voxels), to choose one, then that grid alone
        std::optional<CheckedVdbFile> opened;
        CheckedVdbFile &file = open_checked(opened, path, label);
        openvdb::GridPtrVec meta = file.metadata();
        if (meta.empty())
            throw Error(label + ": an OpenVDB file without grids");
        size_t i = choose(label, meta, selector);
        if (!convertible(*meta[i]))
            throw Error(label + ": grid " + vdb2nvdb::grid_summary(*meta[i]) +
                        " cannot be read: only float and vec3s grids are supported (points, "
                        "integer and double grids are not)");
        out.index = uint32_t(i);
        grid = file.read(i);
        grid->setName(meta[i]->getName());
    } catch (const Error &) {
        throw;
    } catch (const std::exception &e) {
        throw Error(label + ": cannot read as an OpenVDB file (corrupt or truncated?): " +
                    e.what());
    }
    out.read_seconds = since(t0);
    convert_into(std::move(grid), label, fog_level_sets, out);
    return out;
}

std::vector<VdbGridInfo> read_vdb_listing(const std::string &path) {
    const std::string label = opened_label(path);
    try {
        std::optional<CheckedVdbFile> opened;
        std::vector<VdbGridInfo> out;
        for (const openvdb::GridBase::Ptr &g : open_checked(opened, path, label).metadata())
            out.push_back({ printable_text(g->getName()), g->valueType(),
                            uint32_t(g->getGridClass()) });
        return out;
    } catch (const Error &) {
        throw;
    } catch (const std::exception &e) {
        throw Error(label + ": cannot read as an OpenVDB file (corrupt or truncated?): " +
                    e.what());
    }
}

VdbGrid read_nvdb_level_set_as_fog(const std::string &path, uint32_t index) {
    const std::string label = opened_label(path);
    VdbGrid out;
    out.index = index;
    auto t0 = Clock::now();
    openvdb::FloatGrid::Ptr grid;
    std::string name;
    try {
        // NanoVDB's own reader and nanoToOpenVDB: what vdb2nvdb reads a .nvdb
        // input with (tools/vdb2nvdb/read.cpp), for the types a level set has
        nanovdb::GridHandle<nanovdb::HostBuffer> h =
            nanovdb::io::readGrid<nanovdb::HostBuffer>(path, index);
        const nanovdb::GridMetaData *m = h.gridMetaData();
        name = m ? m->shortGridName() : "";
        if (const auto *g = h.grid<float>())
            grid = nanovdb::nanoToOpenVDB(*g);
        else if (const auto *g = h.grid<nanovdb::Fp4>())
            grid = nanovdb::nanoToOpenVDB(*g);
        else if (const auto *g = h.grid<nanovdb::Fp8>())
            grid = nanovdb::nanoToOpenVDB(*g);
        else if (const auto *g = h.grid<nanovdb::Fp16>())
            grid = nanovdb::nanoToOpenVDB(*g);
        else if (const auto *g = h.grid<nanovdb::FpN>())
            grid = nanovdb::nanoToOpenVDB(*g);
        else
            throw Error(label + ": grid " + std::to_string(index) + " (\"" + printable_text(name) +
                        "\"): only float, Fp4, Fp8, Fp16 and FpN level sets can be made fog "
                        "volumes");
    } catch (const Error &) {
        throw;
    } catch (const std::exception &e) {
        throw Error(label + ": cannot read grid " + std::to_string(index) + " as a NanoVDB "
                    "grid (NanoVDB " + std::to_string(NANOVDB_MAJOR_VERSION_NUMBER) + "." +
                    std::to_string(NANOVDB_MINOR_VERSION_NUMBER) + "'s reader): " + e.what());
    }
    if (!grid || grid->getGridClass() != openvdb::GRID_LEVEL_SET)
        throw Error(label + ": grid \"" + printable_text(name) + "\" is not a level set: "
                    "nothing to make a fog volume of");
    grid->setName(name);
    out.read_seconds = since(t0);
    convert_into(std::move(grid), label, true, out);
    return out;
}

bool check_vdb_structure(const std::string &path) {
    initialize_openvdb();
    const std::string label = "\"" + path + "\"";
    try {
        CheckedVdbFile file(path, label);
        file.check_all_roots();
        return true;
    } catch (const CheckedVdbFile::NoOffsets &) {
        return false;
    } catch (const Error &) {
        throw;
    } catch (const std::exception &e) {
        throw Error(label + ": cannot read as an OpenVDB file (corrupt or truncated?): " +
                    e.what());
    }
}

} // namespace nanovdb_loader
