// nanovdbvolume built without OpenVDB: src/loader/vdb_import.cpp compiled
// without NVDB_WITH_OPENVDB (as a build without libopenvdb-dev compiles it),
// so that a .vdb is refused with a message that names the file and says how
// to read it, and nothing else depends on OpenVDB. The build with OpenVDB is
// tested end to end by tests/test_vdb_import.py.

#include <nanovdb_loader/vdb_import.h>
#include <doctest/doctest.h>

#include <string>

TEST_CASE("without OpenVDB, a .vdb is refused with a clear message") {
    CHECK(!nanovdb_loader::vdb_import_available());
    CHECK(nanovdb_loader::is_vdb_path("a/smoke.0001.vdb"));
    CHECK(nanovdb_loader::is_vdb_path("SMOKE.VDB"));
    CHECK(!nanovdb_loader::is_vdb_path("smoke.nvdb"));
    CHECK(!nanovdb_loader::is_vdb_path("vdb"));
    std::string message;
    try {
        nanovdb_loader::import_vdb_grid("frames/smoke.0001.vdb", "density");
    } catch (const nanovdb_loader::Error &e) {
        message = e.what();
    }
    CHECK(message.find("\"frames/smoke.0001.vdb\"") == 0);
    CHECK(message.find("no OpenVDB") != std::string::npos);
    CHECK(message.find("vdb2nvdb") != std::string::npos);
    CHECK(message.find("libopenvdb-dev") != std::string::npos);
}
