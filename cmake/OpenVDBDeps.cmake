# Debian's OpenVDB 10 (libopenvdb-dev) and NanoVDB 32.4 C++ headers
# (libnanovdb-dev), as the imported target nvdb::openvdb. OpenVDB's headers also
# need Boost, TBB and Imath 3.1.

find_path(OPENVDB_INCLUDE_DIR openvdb/openvdb.h)
find_library(OPENVDB_LIBRARY openvdb)
find_library(TBB_LIBRARY tbb)
find_library(IMATH_LIBRARY Imath-3_1)
find_path(IMATH_INCLUDE_DIR Imath/half.h)
find_path(BOOST_INCLUDE_DIR boost/version.hpp)
if (OPENVDB_INCLUDE_DIR AND OPENVDB_LIBRARY AND TBB_LIBRARY AND IMATH_LIBRARY
    AND IMATH_INCLUDE_DIR AND BOOST_INCLUDE_DIR)
  set(NVDB_HAVE_OPENVDB ON)
  add_library(nvdb_openvdb INTERFACE)
  add_library(nvdb::openvdb ALIAS nvdb_openvdb)
  target_include_directories(nvdb_openvdb SYSTEM INTERFACE
    "${OPENVDB_INCLUDE_DIR}" "${IMATH_INCLUDE_DIR}" "${IMATH_INCLUDE_DIR}/Imath"
    "${BOOST_INCLUDE_DIR}" "${PNANOVDB_INCLUDE_DIR}" "${BLOSC_INCLUDE_DIR}")
  target_compile_definitions(nvdb_openvdb INTERFACE NANOVDB_USE_ZIP NANOVDB_USE_BLOSC)
  target_link_libraries(nvdb_openvdb INTERFACE
    "${OPENVDB_LIBRARY}" "${TBB_LIBRARY}" "${IMATH_LIBRARY}"
    ZLIB::ZLIB "${BLOSC_LIBRARY}") # NanoVDB's own writer/reader (ZIP, BLOSC)
else()
  set(NVDB_HAVE_OPENVDB OFF)
  message(WARNING "OpenVDB 10 not found (apt-get install libopenvdb-dev "
                  "libboost-dev libtbb-dev libimath-dev): tools and tests that "
                  "need it are not built.")
endif()
