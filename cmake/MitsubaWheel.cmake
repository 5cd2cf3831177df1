# Locates the pip-installed mitsuba and drjit wheels through the Python
# interpreter and exposes them as the imported target mitsuba_wheel::mitsuba.
#
# The wheels ship their headers and shared libraries. A plugin compiled against
# them must use the same ABI as the wheel's own libmitsuba.so:
#   -mavx2 -mfma -mf16c: without them, Dr.Jit picks another layout for 3-vectors
#   (packet vs. plain arrays) and the plugin silently reads garbage.
#   MI_ENABLE_{LLVM,CUDA,EMBREE,AUTODIFF}: the variant set the wheel was built with.

set(NVDB_MITSUBA_VERSION 3.9.1 CACHE STRING "mitsuba wheel version to build against")
set(NVDB_DRJIT_VERSION   1.5.0 CACHE STRING "drjit wheel version to build against")

find_package(Python 3.8 COMPONENTS Interpreter REQUIRED)

execute_process(
  COMMAND "${Python_EXECUTABLE}" -c
"import os, mitsuba, drjit, nanobind
print(os.path.dirname(mitsuba.__file__))
print(os.path.dirname(drjit.__file__))
print(nanobind.include_dir())
print(mitsuba.__version__)
print(drjit.__version__)"
  OUTPUT_VARIABLE _nvdb_py_out
  ERROR_VARIABLE  _nvdb_py_err
  RESULT_VARIABLE _nvdb_py_res
  OUTPUT_STRIP_TRAILING_WHITESPACE)

if (NOT _nvdb_py_res EQUAL 0)
  message(FATAL_ERROR
    "Could not import mitsuba, drjit and nanobind with ${Python_EXECUTABLE}:\n"
    "${_nvdb_py_err}\nInstall them with: ${Python_EXECUTABLE} -m pip install "
    "mitsuba==${NVDB_MITSUBA_VERSION} drjit==${NVDB_DRJIT_VERSION} nanobind")
endif()

string(REPLACE "\n" ";" _nvdb_py_out "${_nvdb_py_out}")
list(GET _nvdb_py_out 0 MITSUBA_WHEEL_DIR)
list(GET _nvdb_py_out 1 DRJIT_WHEEL_DIR)
list(GET _nvdb_py_out 2 NANOBIND_INCLUDE_DIR)
list(GET _nvdb_py_out 3 _nvdb_mi_version)
list(GET _nvdb_py_out 4 _nvdb_dr_version)

if (NOT _nvdb_mi_version STREQUAL NVDB_MITSUBA_VERSION OR
    NOT _nvdb_dr_version STREQUAL NVDB_DRJIT_VERSION)
  message(FATAL_ERROR
    "Found mitsuba ${_nvdb_mi_version} / drjit ${_nvdb_dr_version}, but this "
    "build is pinned to mitsuba ${NVDB_MITSUBA_VERSION} / drjit "
    "${NVDB_DRJIT_VERSION} (C++ ABI). Install the pinned versions or pass "
    "-DNVDB_MITSUBA_VERSION=... -DNVDB_DRJIT_VERSION=... at your own risk.")
endif()
message(STATUS "mitsuba ${_nvdb_mi_version}: ${MITSUBA_WHEEL_DIR}")
message(STATUS "drjit ${_nvdb_dr_version}: ${DRJIT_WHEEL_DIR}")

find_library(MITSUBA_LIBRARY mitsuba PATHS "${MITSUBA_WHEEL_DIR}" NO_DEFAULT_PATH REQUIRED)
find_library(DRJIT_CORE_LIBRARY drjit-core PATHS "${DRJIT_WHEEL_DIR}" NO_DEFAULT_PATH REQUIRED)
find_library(DRJIT_EXTRA_LIBRARY drjit-extra PATHS "${DRJIT_WHEEL_DIR}" NO_DEFAULT_PATH REQUIRED)
find_library(NANOTHREAD_LIBRARY nanothread PATHS "${DRJIT_WHEEL_DIR}" NO_DEFAULT_PATH REQUIRED)

# Dr.Jit alone (used by the doctest suites, which need no Mitsuba).
add_library(drjit_wheel INTERFACE)
add_library(mitsuba_wheel::drjit ALIAS drjit_wheel)
target_include_directories(drjit_wheel SYSTEM INTERFACE "${DRJIT_WHEEL_DIR}/include")
target_compile_options(drjit_wheel INTERFACE -mavx2 -mfma -mf16c -fno-strict-aliasing)
target_link_libraries(drjit_wheel INTERFACE
  "${DRJIT_EXTRA_LIBRARY}" "${DRJIT_CORE_LIBRARY}" "${NANOTHREAD_LIBRARY}")
set_property(TARGET drjit_wheel PROPERTY INTERFACE_LINK_OPTIONS
  "LINKER:-rpath,${DRJIT_WHEEL_DIR}")

add_library(mitsuba_wheel INTERFACE)
add_library(mitsuba_wheel::mitsuba ALIAS mitsuba_wheel)
target_include_directories(mitsuba_wheel SYSTEM INTERFACE
  "${MITSUBA_WHEEL_DIR}/include"
  "${NANOBIND_INCLUDE_DIR}"
  "${NANOBIND_INCLUDE_DIR}/../ext/robin_map/include")
target_compile_definitions(mitsuba_wheel INTERFACE
  MI_ENABLE_LLVM=1 MI_ENABLE_CUDA=1 MI_ENABLE_EMBREE=1 MI_ENABLE_AUTODIFF=1)
target_link_libraries(mitsuba_wheel INTERFACE "${MITSUBA_LIBRARY}" drjit_wheel)
set_property(TARGET mitsuba_wheel PROPERTY INTERFACE_LINK_OPTIONS
  "LINKER:-rpath,${MITSUBA_WHEEL_DIR}")
