// The .nvdb container (src/loader/container.cpp): list_grids, select_grid,
// read_grid on every file form and codec NanoVDB writes, hostile files, and
// the real files in ../shared/data ($NVDB_SHARED_DATA), read in place.

#include <nanovdb_loader/load.h>
#include <nanovdb_drjit/layout.h>
#include <doctest/doctest.h>

#include "fixtures.h"

#include <optional>

TEST_CASE("grid_type_name and describe_grids") {
    CHECK(nio::grid_type_name(1) == "float");
    CHECK(nio::grid_type_name(2) == "double");
    CHECK(nio::grid_type_name(4) == "int32");
    CHECK(nio::grid_type_name(6) == "Vec3f");
    CHECK(nio::grid_type_name(9) == "Half");
    CHECK(nio::grid_type_name(16) == "FpN");
    CHECK(nio::grid_type_name(19) == "Index");
    CHECK(nio::grid_type_name(20) == "OnIndex");
    CHECK(nio::grid_type_name(22) == "OnIndexMask");
    CHECK(nio::grid_type_name(26) == "UInt8");
    CHECK(nio::grid_type_name(0) == "unknown (0)");
    CHECK(nio::grid_type_name(27) == "unknown (27)");
    CHECK(nio::grid_type_name(0xffffffffu) == "unknown (4294967295)");
    // The 32.4 table agrees with our names where both exist (apart from
    // NanoVDB's spelling of the Fp types, "Float4"...).
    for (uint32_t t = 1; t < uint32_t(nanovdb::GridType::End); ++t) {
        if (t >= 13 && t <= 16) continue;
        CHECK(nio::grid_type_name(t) == nanovdb::toStr(nanovdb::GridType(t)));
    }

    std::vector<nio::GridEntry> grids(2);
    grids[0].name = "density";
    grids[0].grid_type = 1;
    grids[1].name = "temperature";
    grids[1].grid_type = 1;
    CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"temperature\" (float)");
    grids[1].grid_type = 6;
    grids[1].name = "";
    CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"\" (Vec3f)");
}

// =====================================================================================

TEST_CASE("files written by NanoVDB 32.4: list_grids, select_grid, read_grid") {
    // Built once for all subcases (doctest re-runs this body for each)
    static const Handle sphere = fog_sphere("density"), torus = ls_torus("surface"),
                        nans = nan_inf_grid();
    const uint32_t version32_4 = nanovdb::Version().id();

    for (const auto codec : { nanovdb::io::Codec::NONE, nanovdb::io::Codec::ZIP,
                              nanovdb::io::Codec::BLOSC }) {
        const std::string cname = nanovdb::io::toStr(codec);
        SUBCASE(("one grid, " + cname).c_str()) {
            const std::string path = tmp_path("one_" + cname + ".nvdb");
            nanovdb::io::writeGrid(path, sphere, codec);
            const auto grids = nio::list_grids(path);
            REQUIRE(grids.size() == 1);
            const auto &e = grids[0];
            CHECK(e.name == "density");
            CHECK(e.grid_type == 1);
            CHECK(e.grid_class == uint32_t(nanovdb::GridClass::FogVolume));
            CHECK(e.grid_size == sphere.size());
            CHECK(e.codec == nio::Codec(uint16_t(codec)));
            CHECK(e.version == version32_4);
            CHECK(e.segment == 0);
            CHECK(!e.raw);
            CHECK(e.file_offset == 16 + 176 + std::string("density").size() + 1);
            CHECK(e.file_offset + e.file_size == fs::file_size(path));
            if (codec == nanovdb::io::Codec::NONE) CHECK(e.file_size == e.grid_size);
            else CHECK(e.file_size < e.grid_size);

            const Aligned buf = load(path, e);
            CHECK(buf.bytes() == handle_bytes(sphere));
            const Handle ref = nanovdb::io::readGrid(path, 0);
            CHECK(buf.bytes() == handle_bytes(ref));
            const auto info = nio::validate_grid(path, buf.data(), buf.size);
            check_info_against_nanovdb(info, *ref.grid<float>());
            CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
        }
        SUBCASE(("three grids in one segment, " + cname).c_str()) {
            const std::string path = tmp_path("three_" + cname + ".nvdb");
            std::vector<Handle> handles;
            handles.push_back(fog_sphere("density"));
            handles.push_back(ls_torus("surface"));
            handles.push_back(nan_inf_grid());
            nanovdb::io::writeGrids(path, handles, codec);
            const auto grids = nio::list_grids(path);
            REQUIRE(grids.size() == 3);
            CHECK(nio::describe_grids(grids) ==
                  "0: \"density\" (float), 1: \"surface\" (float), 2: \"nan_inf\" (float)");
            uint64_t expect_offset = 16;
            for (const auto &g : grids) expect_offset += 176 + g.name.size() + 1;
            for (size_t i = 0; i < grids.size(); ++i) {
                INFO("grid " << i);
                CHECK(grids[i].segment == 0);
                CHECK(grids[i].file_offset == expect_offset);
                expect_offset += grids[i].file_size;
                CHECK(grids[i].grid_size == handles[i].size());
                const Aligned buf = load(path, grids[i]);
                CHECK(buf.bytes() == handle_bytes(handles[i]));
                CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
                CHECK_NOTHROW(nio::validate_grid(path, buf.data(), buf.size));
            }
            CHECK(expect_offset == fs::file_size(path));
            CHECK(&nio::select_grid(path, grids, "surface") == &grids[1]);
            CHECK(&nio::select_grid(path, grids, "nan_inf") == &grids[2]);
            CHECK(&nio::select_grid(path, grids, "2") == &grids[2]);
            CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
            CHECK_IO_ERROR(nio::select_grid(path, grids, "3"), path, "\"3\" not found",
                           "0: \"density\" (float), 1: \"surface\" (float), 2: \"nan_inf\" (float)");
            CHECK_IO_ERROR(nio::select_grid(path, grids, "temperature"), path,
                           "\"temperature\" not found", "1: \"surface\" (float)");
            CHECK_IO_ERROR(nio::select_grid(path, grids, "-1"), path, "not found");
        }
    }
    SUBCASE("two segments (two files concatenated), different codecs") {
        const std::string a = tmp_path("seg_a.nvdb"), b = tmp_path("seg_b.nvdb"),
                          path = tmp_path("two_segments.nvdb");
        std::vector<Handle> first;
        first.push_back(fog_sphere("density"));
        first.push_back(ls_torus("surface"));
        nanovdb::io::writeGrids(a, first, nanovdb::io::Codec::ZIP);
        nanovdb::io::writeGrid(b, nans, nanovdb::io::Codec::BLOSC);
        Bytes all = read_bytes(a);
        const Bytes tail = read_bytes(b);
        all.insert(all.end(), tail.begin(), tail.end());
        write_bytes(path, all);

        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 3);
        CHECK(grids[0].segment == 0);
        CHECK(grids[1].segment == 0);
        CHECK(grids[2].segment == 1);
        CHECK(grids[0].codec == nio::Codec::Zip);
        CHECK(grids[2].codec == nio::Codec::Blosc);
        CHECK(grids[2].file_offset == read_bytes(a).size() + 16 + 176 + 8);
        for (size_t i = 0; i < 3; ++i) {
            INFO("grid " << i);
            const Aligned buf = load(path, grids[i]);
            CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
        }
        CHECK(load(path, grids[2]).bytes() == handle_bytes(nans));
        CHECK(&nio::select_grid(path, grids, "nan_inf") == &grids[2]);
    }
    SUBCASE("mixed value types: only the supported types are selectable") {
        const std::string path = tmp_path("mixed.nvdb");
        std::vector<Handle> handles;
        handles.push_back(typed_grid<double>("dbl", 2.5));
        handles.push_back(typed_grid<int32_t>("ints", 7));
        handles.push_back(typed_grid<nanovdb::Vec3f>("vel", nanovdb::Vec3f(1, 2, 3)));
        handles.push_back(fog_sphere("density"));
        nanovdb::io::writeGrids(path, handles, nanovdb::io::Codec::ZIP);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 4);
        CHECK(grids[0].grid_type == 2);
        CHECK(grids[1].grid_type == 4);
        CHECK(grids[2].grid_type == 6);
        CHECK(grids[3].grid_type == 1);
        // The first grid of a supported type: the Vec3f one
        CHECK(&nio::select_grid(path, grids, "") == &grids[2]);
        CHECK(&nio::select_grid(path, grids, "density") == &grids[3]);
        CHECK(&nio::select_grid(path, grids, "2") == &grids[2]);
        CHECK_IO_ERROR(nio::select_grid(path, grids, "dbl"), path, "\"dbl\"", "type double",
                       "not supported",
                       "supported types: float, Half, Fp4, Fp8, Fp16, FpN, Vec3f");
        CHECK_IO_ERROR(nio::select_grid(path, grids, "ints"), path, "type int32", "not supported");
        // Non-float payloads still decode byte-exactly.
        for (size_t i = 0; i < 3; ++i)
            CHECK(load(path, grids[i]).bytes() == handle_bytes(handles[i]));

        const std::string nofloat = tmp_path("nofloat.nvdb");
        handles.pop_back();
        handles.pop_back();
        nanovdb::io::writeGrids(nofloat, handles, nanovdb::io::Codec::NONE);
        const auto g2 = nio::list_grids(nofloat);
        CHECK_IO_ERROR(nio::select_grid(nofloat, g2, ""), nofloat,
                       "no grid of a supported type", "supported types: float, Half",
                       "0: \"dbl\" (double), 1: \"ints\" (int32)");
    }
    SUBCASE("names take priority over indices; unnamed grids") {
        const std::string path = tmp_path("names.nvdb");
        std::vector<Handle> handles;
        handles.push_back(fog_sphere("a"));
        handles.push_back(fog_sphere("0"));
        handles.push_back(fog_sphere(""));
        nanovdb::io::writeGrids(path, handles, nanovdb::io::Codec::NONE);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 3);
        CHECK(grids[2].name.empty());
        CHECK(&nio::select_grid(path, grids, "0") == &grids[1]); // the name "0"
        CHECK(&nio::select_grid(path, grids, "2") == &grids[2]); // index 2
        CHECK(&nio::select_grid(path, grids, "a") == &grids[0]);
        CHECK(&nio::select_grid(path, grids, "") == &grids[0]);
        CHECK_IO_ERROR(nio::select_grid(path, grids, "99999999999999999999999"), path,
                       "not found", "2: \"\" (float)");
    }
    SUBCASE("select_grids: the 6-channel pair X[0:3], X[3:6]") {
        const std::string path = tmp_path("pairs.nvdb");
        std::vector<Handle> handles;
        handles.push_back(typed_grid<nanovdb::Vec3f>("S[0:3]", nanovdb::Vec3f(1, 2, 3)));
        handles.push_back(typed_grid<nanovdb::Vec3f>("S[3:6]", nanovdb::Vec3f(4, 5, 6)));
        handles.push_back(fog_sphere("density"));
        handles.push_back(typed_grid<nanovdb::Vec3f>("T", nanovdb::Vec3f(1, 1, 1)));
        handles.push_back(typed_grid<nanovdb::Vec3f>("T[0:3]", nanovdb::Vec3f(1, 1, 1)));
        handles.push_back(typed_grid<nanovdb::Vec3f>("T[3:6]", nanovdb::Vec3f(1, 1, 1)));
        handles.push_back(typed_grid<nanovdb::Vec3f>("U[0:3]", nanovdb::Vec3f(1, 1, 1)));
        handles.push_back(fog_sphere("U[3:6]"));
        nanovdb::io::writeGrids(path, handles, nanovdb::io::Codec::NONE);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 8);
        // X asked for, no X: the pair
        nio::GridChoice c = nio::select_grids(path, grids, "S");
        CHECK(c.first == &grids[0]);
        CHECK(c.second == &grids[1]);
        CHECK(c.name == "S");
        // none asked for, the default is S[0:3]: the pair too
        c = nio::select_grids(path, grids, "");
        CHECK(c.first == &grids[0]);
        CHECK(c.second == &grids[1]);
        // a grid of that name exists: it, alone
        c = nio::select_grids(path, grids, "T");
        CHECK(c.first == &grids[3]);
        CHECK(c.second == nullptr);
        CHECK(c.name == "T");
        // a half of a pair by its own name, an index: one grid
        c = nio::select_grids(path, grids, "S[3:6]");
        CHECK(c.first == &grids[1]);
        CHECK(c.second == nullptr);
        CHECK(nio::select_grids(path, grids, "2").first == &grids[2]);
        // a pair whose halves are not both Vec3f
        CHECK_IO_ERROR(nio::select_grids(path, grids, "U"), path, "6-channel pair",
                       "\"U[0:3]\", \"U[3:6]\" must be two Vec3f grids", "\"U[3:6]\" is float");
        // no pair, no grid: select_grid's error
        CHECK_IO_ERROR(nio::select_grids(path, grids, "V"), path, "\"V\" not found");
    }
}

// =====================================================================================
TEST_CASE("newer file forms: NanoVDB2 header, NanoVDB1 grids, raw grid buffers") {
    static const Handle sphere = fog_sphere("density"), torus = ls_torus("surface");
    static const Bytes sphere_bytes = handle_bytes(sphere), torus_bytes = handle_bytes(torus);
    const auto ref_info = validate_handle(sphere, "ref");

    SUBCASE("32.8+: NanoVDB2 file header, NanoVDB1 grid magic, version 32.8.0") {
        const std::string base = tmp_path("v2_base.nvdb"), path = tmp_path("v2.nvdb");
        nanovdb::io::writeGrid(base, sphere, nanovdb::io::Codec::NONE);
        Bytes b = read_bytes(base);
        const auto grids0 = nio::list_grids(base);
        std::memcpy(b.data(), "NanoVDB2", 8);
        poke<uint32_t>(b, 8, packed_version(32, 8, 0));
        std::memcpy(b.data() + grids0[0].file_offset, "NanoVDB1", 8);
        write_bytes(path, b);

        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].version == packed_version(32, 8, 0));
        CHECK(grids[0].name == "density");
        CHECK(!grids[0].raw);
        const Aligned buf = load(path, grids[0]);
        Bytes expect = sphere_bytes;
        std::memcpy(expect.data(), "NanoVDB1", 8);
        CHECK(buf.bytes() == expect);
        const auto info = nio::validate_grid(path, buf.data(), buf.size);
        CHECK(info.values().max == ref_info.values().max);
        CHECK(info.summary().active_voxel_count == ref_info.summary().active_voxel_count);
        check_info_against_nanovdb(info, *sphere.grid<float>());
    }
    SUBCASE("raw grid buffer, NanoVDB0 grid magic (32.6/32.7)") {
        const std::string path = tmp_path("raw0.nvdb");
        write_bytes(path, sphere_bytes);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        const auto &e = grids[0];
        CHECK(e.raw);
        CHECK(e.name == "density");
        CHECK(e.grid_type == 1);
        CHECK(e.grid_class == uint32_t(nanovdb::GridClass::FogVolume));
        CHECK(e.grid_size == sphere.size());
        CHECK(e.file_offset == 0);
        CHECK(e.file_size == sphere.size());
        CHECK(e.codec == nio::Codec::None);
        CHECK(e.version == sphere.grid<float>()->version().id());
        const Aligned buf = load(path, e);
        CHECK(buf.bytes() == sphere_bytes);
        check_info_against_nanovdb(nio::validate_grid(path, buf.data(), buf.size),
                                   *sphere.grid<float>());
    }
    SUBCASE("raw grid buffer, NanoVDB1 grid magic, two grids back to back") {
        const std::string path = tmp_path("raw1.nvdb");
        Bytes b = sphere_bytes;
        b.insert(b.end(), torus_bytes.begin(), torus_bytes.end());
        std::memcpy(b.data(), "NanoVDB1", 8);
        std::memcpy(b.data() + sphere_bytes.size(), "NanoVDB1", 8);
        write_bytes(path, b);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 2);
        CHECK(nio::describe_grids(grids) == "0: \"density\" (float), 1: \"surface\" (float)");
        CHECK(grids[1].file_offset == sphere_bytes.size());
        CHECK(grids[1].raw);
        const Aligned buf = load(path, nio::select_grid(path, grids, "surface"));
        Bytes expect = torus_bytes;
        std::memcpy(expect.data(), "NanoVDB1", 8);
        CHECK(buf.bytes() == expect);
        check_info_against_nanovdb(nio::validate_grid(path, buf.data(), buf.size),
                                   *torus.grid<float>());
    }
    SUBCASE("raw grid whose checksum looks like a segment header") {
        // Bytes 8..15 of a grid are its checksum; make them read as a 32.x
        // segment header (version, 1 grid, codec NONE). The segment reading
        // fails, and the loader falls back to the raw reading.
        const std::string path = tmp_path("raw_ambiguous.nvdb");
        Bytes b = sphere_bytes;
        poke<uint32_t>(b, 8, packed_version(32, 4, 2));
        poke<uint16_t>(b, 12, 1);
        poke<uint16_t>(b, 14, 0);
        write_bytes(path, b);
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].raw);
        CHECK(load(path, grids[0]).bytes() == b);
    }
    SUBCASE("raw grid buffer truncated") {
        const std::string path = tmp_path("raw_truncated.nvdb");
        write_bytes(path, Bytes(sphere_bytes.begin(), sphere_bytes.end() - 100));
        CHECK_IO_ERROR(nio::list_grids(path), path, "beyond the end of the file");
        Bytes two = sphere_bytes;
        two.insert(two.end(), torus_bytes.begin(), torus_bytes.begin() + 300);
        write_bytes(path, two);
        CHECK_IO_ERROR(nio::list_grids(path), path, "grid 1", "truncated grid header");
    }
}

// =====================================================================================
TEST_CASE("list_grids and read_grid reject hostile files") {
    static const Handle sphere = fog_sphere("density"), torus = ls_torus("surface");
    static const std::vector<Handle> two = [] {
        std::vector<Handle> v;
        v.push_back(fog_sphere("density"));
        v.push_back(ls_torus("surface"));
        return v;
    }();
    const std::string none_path = tmp_path("h_none.nvdb"), zip_path = tmp_path("h_zip.nvdb"),
                      blosc_path = tmp_path("h_blosc.nvdb"), two_path = tmp_path("h_two.nvdb");
    nanovdb::io::writeGrid(none_path, sphere, nanovdb::io::Codec::NONE);
    nanovdb::io::writeGrid(zip_path, sphere, nanovdb::io::Codec::ZIP);
    nanovdb::io::writeGrid(blosc_path, sphere, nanovdb::io::Codec::BLOSC);
    nanovdb::io::writeGrids(two_path, two, nanovdb::io::Codec::ZIP);
    const Bytes none = read_bytes(none_path), zip = read_bytes(zip_path),
                blosc = read_bytes(blosc_path), twob = read_bytes(two_path);
    const uint64_t payload = 16 + 176 + 8; // header + metadata + "density\0"
    const std::string p = tmp_path("hostile.nvdb");
    auto write = [&](const Bytes &b) { write_bytes(p, b); };

    SUBCASE("missing file, directory") {
        const std::string missing = tmp_path("does_not_exist.nvdb");
        CHECK_IO_ERROR(nio::list_grids(missing), missing, "not found");
        const std::string dir = fs::path(p).parent_path().string();
        CHECK_IO_ERROR(nio::list_grids(dir), dir, "directory");
        nio::GridEntry e = nio::list_grids(none_path)[0];
        CHECK_IO_ERROR(nio::read_grid(missing, e, nullptr), missing, "not found");
    }
    SUBCASE("empty file") {
        write({});
        CHECK_IO_ERROR(nio::list_grids(p), p, "empty");
    }
    SUBCASE("random bytes") {
        std::mt19937 rng(1234);
        Bytes b(4096);
        for (auto &c : b) c = uint8_t(rng());
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "first 8 bytes");
        write(Bytes(b.begin(), b.begin() + 5));
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "5 bytes");
    }
    SUBCASE("wrong magic; an OpenVDB file") {
        Bytes b = none;
        std::memcpy(b.data(), "NanoVDBX", 8);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "not a NanoVDB file", "NanoVDBX");
        const std::string vdb = shared_data_dir() + "/openvdb_sphere_ls.vdb";
        if (fs::exists(vdb))
            CHECK_IO_ERROR(nio::list_grids(vdb), vdb, "not a NanoVDB file", "OpenVDB");
    }
    SUBCASE("byte-swapped magic") {
        Bytes b = none;
        std::reverse(b.begin(), b.begin() + 8);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "byte-swapped", "big-endian");
    }
    SUBCASE("major version 31 and 33") {
        Bytes b = none;
        poke<uint32_t>(b, 8, packed_version(31, 4, 2));
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "version 31.4.2", "only major version 32");
        poke<uint32_t>(b, 8, packed_version(33, 0, 1));
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "version 33.0.1", "only major version 32");
    }
    SUBCASE("truncated header") {
        write(Bytes(none.begin(), none.begin() + 12));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated segment header");
    }
    SUBCASE("truncated metadata") {
        write(Bytes(none.begin(), none.begin() + 16 + 100));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated metadata");
        // Grid count larger than the metadata that follows.
        Bytes b = none;
        poke<uint16_t>(b, 12, 60000);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated metadata", "60000 grids");
    }
    SUBCASE("truncated name") {
        write(Bytes(none.begin(), none.begin() + 16 + 176 + 3));
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated name");
        Bytes b = none;
        poke<uint32_t>(b, 16 + 136, 0xfffffff0u); // absurd name size
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "truncated name", "4294967280");
    }
    SUBCASE("truncated payload") {
        write(Bytes(zip.begin(), zip.end() - 10));
        CHECK_IO_ERROR(nio::list_grids(p), p, "\"density\"", "beyond the end of the file");
        // The file shrinks after list_grids: read_grid notices.
        write(zip);
        const auto grids = nio::list_grids(p);
        write(Bytes(zip.begin(), zip.end() - 10));
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "truncated payload");
    }
    SUBCASE("payload offset beyond EOF") {
        const auto grids = nio::list_grids(two_path);
        REQUIRE(grids.size() == 2);
        // Cut right after the first payload: the second starts at EOF.
        write(Bytes(twob.begin(), twob.begin() + grids[1].file_offset));
        CHECK_IO_ERROR(nio::list_grids(p), p, "grid 1 \"surface\"", "beyond the end of the file");
        // A first grid whose payload size runs past the end of the file.
        Bytes b = twob;
        poke<uint64_t>(b, 16 + 8, uint64_t(1) << 62);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "grid 0 \"density\"", "beyond the end of the file");
    }
    SUBCASE("absurd grid_size: rejected before any allocation") {
        Bytes b = none;
        poke<uint64_t>(b, 16, uint64_t(1) << 60);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "1152921504606846976", "16 GiB");
        b = zip;
        poke<uint64_t>(b, 16, uint64_t(1) << 33); // 8 GiB from a few KiB of zlib
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "8589934592", "implausible", "1100:1");
        b = none;
        poke<uint64_t>(b, 16, none.size()); // NONE: grid size must equal payload size
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "uncompressed grid size", "differs");
        b = none;
        poke<uint64_t>(b, 16, 100);
        poke<uint64_t>(b, 24, 100);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "100 bytes", "smaller");
        // read_grid applies the same limits to an entry it is handed.
        nio::GridEntry e = nio::list_grids(none_path)[0];
        e.grid_size = uint64_t(1) << 60;
        CHECK_IO_ERROR(nio::read_grid(none_path, e, nullptr), none_path, "16 GiB");
    }
    SUBCASE("unknown codec") {
        Bytes b = none;
        poke<uint16_t>(b, 14, 7);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "unknown codec 7");
    }
    SUBCASE("zero grids") {
        Bytes b = none;
        poke<uint16_t>(b, 12, 0);
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "zero grids");
    }
    SUBCASE("trailing garbage after the last segment") {
        Bytes b = none;
        const Bytes junk(40, 0xab);
        b.insert(b.end(), junk.begin(), junk.end());
        write(b);
        CHECK_IO_ERROR(nio::list_grids(p), p, "segment 1", "expected a NanoVDB segment header");
    }
    SUBCASE("corrupt zlib stream") {
        Bytes b = zip;
        b[payload + 8] = 0; // zlib header (78 9C)
        b[payload + 9] = 0;
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "corrupt zlib stream");
        b = zip;
        for (uint64_t i = payload + 8 + 40; i < payload + 8 + 80; ++i) b[i] ^= 0x5a;
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "zlib");
    }
    SUBCASE("zlib stream decoding to another size than grid_size") {
        Bytes b = zip;
        poke<uint64_t>(b, 16, sphere.size() - 32);
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "more than the grid size");
        poke<uint64_t>(b, 16, sphere.size() + 32);
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       ("decodes to " + std::to_string(sphere.size())));
    }
    SUBCASE("zlib size prefix larger than the payload") {
        Bytes b = zip;
        poke<uint64_t>(b, payload, uint64_t(1) << 40);
        write(b);
        const auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "truncated payload", "zlib stream");
    }
    SUBCASE("corrupt blosc chunk") {
        Bytes b = blosc;
        for (uint64_t i = payload + 8; i < payload + 8 + 16; ++i) b[i] ^= 0xff; // header
        write(b);
        auto grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "blosc chunk 0");
        b = blosc;
        poke<uint64_t>(b, 16, sphere.size() + 64); // grid_size disagrees with the chunk
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "blosc chunk 0", "expected");
        b = blosc;
        poke<uint64_t>(b, payload, uint64_t(1) << 30); // a chunk claiming 1 GiB: refused
        write(b);                                       // from the payload, before allocating
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "blosc chunk 0");
        b = blosc;
        poke<uint64_t>(b, payload, 3); // chunk smaller than a blosc header
        write(b);
        grids = nio::list_grids(p);
        CHECK_IO_ERROR(nio::read_grid(p, grids[0], Aligned(grids[0].grid_size).data()), p,
                       "smaller than a blosc header");
    }
}

// =====================================================================================
TEST_CASE("the real files in shared/data" * doctest::skip(!fs::is_directory(shared_data_dir()))) {
    const std::string dir = shared_data_dir();
    std::vector<std::string> files;
    for (const auto &entry : fs::directory_iterator(dir))
        if (entry.path().extension() == ".nvdb") files.push_back(entry.path().string());
    std::sort(files.begin(), files.end());
    CHECK(files.size() >= 5);

    SUBCASE("every .nvdb: grids of the supported types load and validate; float grids "
            "match NanoVDB 32.4's reader") {
        for (const auto &path : files) {
            INFO("file: " << path);
            std::vector<nio::GridEntry> grids;
            CHECK_NOTHROW(grids = nio::list_grids(path));
            for (size_t i = 0; i < grids.size(); ++i) {
                INFO("grid " << i << ": " << grids[i].name);
                if (!nanovdb_drjit::layout::value_type(grids[i].grid_type)) {
                    CHECK_IO_ERROR(nio::select_grid(path, grids, std::to_string(i)), path,
                                   nio::grid_type_name(grids[i].grid_type), "not supported");
                    continue;
                }
                const auto &e = nio::select_grid(path, grids, std::to_string(i));
                const Aligned buf = load(path, e);
                if (grids[i].grid_type == nanovdb_drjit::layout::GRID_TYPE_ONINDEX) {
                    // values from the blind data (tests/io/test_index_grid.cpp)
                    Aligned dst(e.grid_size);
                    CHECK_NOTHROW(nio::decode_grid(path, e, dst.data(), e.grid_size,
                                                   nio::InvalidValues::Error));
                    continue;
                }
                std::optional<nio::ValidatedGrid> info;
                CHECK_NOTHROW(info = nio::validate_grid(path, buf.data(), buf.size));
                if (grids[i].grid_type != 1)
                    continue; // the typed grids: tests/test_value_types.cpp
                // NanoVDB 32.4 reads these files (major 32 only is checked).
                const Handle ref = nanovdb::io::readGrid(path, i);
                CHECK(buf.bytes() == handle_bytes(ref));
                REQUIRE(ref.grid<float>());
                REQUIRE(info);
                check_info_against_nanovdb(*info, *ref.grid<float>());
            }
        }
    }
    SUBCASE("warp torus level set (32.3.3, ZIP)") {
        const std::string path = dir + "/warp_torus_ls_zip_32.3.3.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].name == "surface");
        CHECK(grids[0].version == packed_version(32, 3, 3));
        CHECK(grids[0].codec == nio::Codec::Zip);
        CHECK(grids[0].grid_class == 1); // level set
        const Aligned buf = load(path, nio::select_grid(path, grids, ""));
        const auto info = nio::validate_grid(path, buf.data(), buf.size);
        CHECK(info.summary().background == doctest::Approx(0.3f));
        CHECK(info.summary().bbox_min[1] == -5);
        CHECK(info.summary().bbox_max[1] == 5);
        CHECK(info.summary().active_voxel_count == 3001);
        CHECK(info.summary().voxel_size[0] == doctest::Approx(0.1));
    }
    SUBCASE("warp int32 grid (32.3.3, unnamed): clear rejection; Vec3f: selected") {
        const std::string path = dir + "/warp_int32_zip_32.3.3.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].name.empty());
        CHECK(nio::grid_type_name(grids[0].grid_type) == "int32");
        CHECK_IO_ERROR(nio::select_grid(path, grids, ""), path, "no grid of a supported type",
                       "int32");
        CHECK_IO_ERROR(nio::select_grid(path, grids, "0"), path, "has type int32",
                       "not supported");
        // The payload still decodes and equals NanoVDB's.
        CHECK(load(path, grids[0]).bytes() == handle_bytes(nanovdb::io::readGrid(path, 0)));
        const std::string vec = dir + "/warp_vec3f_zip_32.3.3.nvdb";
        const auto vgrids = nio::list_grids(vec);
        REQUIRE(vgrids.size() == 1);
        CHECK(nio::grid_type_name(vgrids[0].grid_type) == "Vec3f");
        CHECK(&nio::select_grid(vec, vgrids, "") == &vgrids[0]);
    }
    SUBCASE("warp OnIndex grids (32.6.1, two grids in one segment)") {
        const std::string path = dir + "/warp_onindex_2grids_zip_32.6.1.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 2);
        CHECK(nio::describe_grids(grids) == "0: \"grid-0\" (OnIndex), 1: \"grid-1\" (OnIndex)");
        CHECK(grids[0].version == packed_version(32, 6, 1));
        CHECK(grids[1].segment == 0);
        CHECK(&nio::select_grid(path, grids, "grid-1") == &grids[1]);
        for (size_t i = 0; i < 2; ++i) {
            const Aligned buf = load(path, grids[i]);
            CHECK(buf.bytes() == handle_bytes(nanovdb::io::readGrid(path, i)));
            // An index grid needs its values: without, its indices have none
            CHECK_IO_ERROR(nio::validate_grid(path, buf.data(), buf.size), path,
                           "OnIndex leaf 0", "but the grid has 0 values");
        }
    }
    SUBCASE("fVDB batch of 4 grids under one metadata entry (32.5.0, BLOSC)") {
        // Reading: the metadata's single grid "z" is the *first* grid of the
        // decoded payload; read_grid returns the whole decoded payload
        // (grid_size bytes, byte-identical to NanoVDB's readGrid), and
        // validate_grid uses the first grid's own mGridSize.
        const std::string path = dir + "/fvdb_batch4_ls_blosc_32.5.0.nvdb";
        const auto grids = nio::list_grids(path);
        REQUIRE(grids.size() == 1);
        CHECK(grids[0].name == "z");
        CHECK(grids[0].codec == nio::Codec::Blosc);
        CHECK(grids[0].version == packed_version(32, 5, 0));
        CHECK(grids[0].grid_size == 9243328);
        const Aligned buf = load(path, nio::select_grid(path, grids, "z"));
        const Handle ref = nanovdb::io::readGrid(path, 0);
        CHECK(buf.bytes() == handle_bytes(ref));
        const auto info = nio::validate_grid(path, buf.data(), buf.size);
        check_info_against_nanovdb(info, *ref.grid<float>());
        const Bytes all = buf.bytes();
        CHECK(peek<uint64_t>(all, 32) < grids[0].grid_size);
        // Walk the payload: 4 grids back to back, each valid on its own.
        uint64_t offset = 0;
        int count = 0;
        while (offset < all.size() && count < 10) {
            INFO("batch grid " << count << " at byte " << offset);
            CHECK(peek<uint32_t>(all, offset + 24) == uint32_t(count)); // mGridIndex
            CHECK(peek<uint32_t>(all, offset + 28) == 4u);              // mGridCount
            CHECK_NOTHROW(nio::validate_grid(path, all.data() + offset, all.size() - offset));
            offset += peek<uint64_t>(all, offset + 32);
            ++count;
        }
        CHECK(count == 4);
        CHECK(offset == all.size());
    }
}

// =====================================================================================
