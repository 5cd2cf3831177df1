/*
    nanovdb_drjit/traverse.h -- the JIT members of a device-side structure,
    for Dr.Jit's traversal of objects (frozen functions, dr.freeze)

    A Mitsuba plugin lists its JIT members in MI_TRAVERSE_CB; a structure of
    ours that the plugin holds (GridSampler, Reader, MajorantGrid) lists its
    own with NVDB_TRAVERSE, and the plugin lists just the structure: Dr.Jit's
    traverse_1_fn_ro/rw find the traverse_1_cb_ro/rw methods this generates.
    Members that are not JIT arrays (host values, scalar-variant pointers)
    are ignored by the traversal. (The plugin's MI_TRAVERSE_CB decides
    whether to traverse at all.) Only drjit/array_traverse.h is needed, so
    the headers stay usable without Mitsuba (and nanobind), as in the tests.
*/

#pragma once

#include <drjit/array_traverse.h>
#include <drjit/map.h>

#include <cstdint>

#define NVDB_TRAVERSE_RO(member) drjit::traverse_1_fn_ro(member, payload, fn);
#define NVDB_TRAVERSE_RW(member) drjit::traverse_1_fn_rw(member, payload, fn);

#define NVDB_TRAVERSE(...)                                                     \
    void traverse_1_cb_ro(void *payload,                                       \
                          void (*fn)(void *, uint64_t, const char *,           \
                                     const char *)) const {                    \
        (void) payload; (void) fn;                                             \
        DRJIT_MAP(NVDB_TRAVERSE_RO, __VA_ARGS__)                               \
    }                                                                          \
    void traverse_1_cb_rw(void *payload,                                       \
                          uint64_t (*fn)(void *, uint64_t, const char *,       \
                                         const char *)) {                      \
        (void) payload; (void) fn;                                             \
        DRJIT_MAP(NVDB_TRAVERSE_RW, __VA_ARGS__)                               \
    }
