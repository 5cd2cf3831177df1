/*
    nanovdb_drjit/layout.h -- the byte layout of a NanoVDB grid, in one place

    Every offset and size that the device traversal (pnanovdb.h and the fast
    readers) and the host loader (src/loader/) use, under PNanoVDB's own
    names (nanovdb/PNanoVDB.h, NanoVDB 32.4, Copyright Contributors to the
    OpenVDB Project, SPDX-License-Identifier: MPL-2.0): PNANOVDB_GRID_OFF_*
    becomes GRID_OFF_*, pnanovdb_grid_type_constants[] becomes
    grid_type_constants(). No offset is written anywhere else.

    Plain C++17, no Dr.Jit: the loader includes it too. All offsets are in
    bytes, relative to the start of the structure they belong to. The numbers
    hold for every NanoVDB 32.x version; tests/test_translation.cpp checks each
    one against PNanoVDB's macros and table.

    A new value type is a new row of grid_type_constants() (and its value
    decoding), not new offsets elsewhere.
*/

#pragma once

#include <cstdint>
#include <type_traits>

namespace nanovdb_drjit::layout {

// ---- Magics and version (PNANOVDB_MAGIC_*, PNANOVDB_MAJOR_VERSION_NUMBER) ----

/// "NanoVDB0": file/segment header and grid magic up to NanoVDB 32.7
static constexpr uint64_t MAGIC_NUMBER = 0x304244566f6e614eull;
/// "NanoVDB1": grid magic (GridData.mMagic) from 32.8 on
static constexpr uint64_t MAGIC_GRID   = 0x314244566f6e614eull;
/// "NanoVDB2": file/segment header magic from 32.8 on
static constexpr uint64_t MAGIC_FILE   = 0x324244566f6e614eull;
static constexpr uint32_t MAJOR_VERSION_NUMBER = 32;

/// Version word: major << 21 | minor << 10 | patch
constexpr uint32_t version_major(uint32_t version) { return version >> 21; }

// ---- Grid types (PNANOVDB_GRID_TYPE_*) ----------------------------------------

static constexpr uint32_t GRID_TYPE_FLOAT = 1;
static constexpr uint32_t GRID_TYPE_VEC3F = 6;
static constexpr uint32_t GRID_TYPE_HALF  = 9;
static constexpr uint32_t GRID_TYPE_FP4   = 13;
static constexpr uint32_t GRID_TYPE_FP8   = 14;
static constexpr uint32_t GRID_TYPE_FP16  = 15;
static constexpr uint32_t GRID_TYPE_FPN   = 16;
/// PNANOVDB_GRID_TYPE_END: the first value past PNanoVDB 32.4's table
static constexpr uint32_t GRID_TYPE_END   = 20;
/// PNANOVDB_GRID_TYPE_ONINDEX (NanoVDB 32.5 on): an index grid. Its tree maps
/// each active voxel and active tile to a value index (0: the background,
/// 1..N the values, which live elsewhere: a blind channel, or an array)
static constexpr uint32_t GRID_TYPE_ONINDEX = 20;

// ---- Map (PNANOVDB_MAP_*) --------------------------------------------------------

static constexpr uint32_t MAP_SIZE        = 264;
static constexpr uint32_t MAP_OFF_MATD    = 88;   ///< 3x3 double, row-major, index -> world
static constexpr uint32_t MAP_OFF_INVMATD = 160;  ///< its inverse
static constexpr uint32_t MAP_OFF_VECD    = 232;  ///< 3 doubles, the translation

// ---- Grid (PNANOVDB_GRID_*): GridData, at the start of every grid -------------

static constexpr uint32_t GRID_SIZE                = 672;
static constexpr uint32_t GRID_OFF_MAGIC           = 0;
static constexpr uint32_t GRID_OFF_CHECKSUM        = 8;
static constexpr uint32_t GRID_OFF_VERSION         = 16;
static constexpr uint32_t GRID_OFF_GRID_SIZE       = 32;
static constexpr uint32_t GRID_OFF_GRID_NAME       = 40;
static constexpr uint32_t GRID_NAME_SIZE           = 256; ///< PNANOVDB_GRID_OFF_MAP - ..._GRID_NAME
static constexpr uint32_t GRID_OFF_MAP             = 296;
static constexpr uint32_t GRID_OFF_VOXEL_SIZE      = 608;
static constexpr uint32_t GRID_OFF_GRID_CLASS      = 632;
static constexpr uint32_t GRID_OFF_GRID_TYPE       = 636;

// ---- Tree (PNANOVDB_TREE_*): TreeData, right after GridData ---------------------
// Node offsets are uint64 bytes relative to the tree; counts are uint32.

static constexpr uint32_t TREE_SIZE                  = 64;
static constexpr uint32_t TREE_OFF_NODE_OFFSET_LEAF  = 0;
static constexpr uint32_t TREE_OFF_NODE_OFFSET_LOWER = 8;
static constexpr uint32_t TREE_OFF_NODE_OFFSET_UPPER = 16;
static constexpr uint32_t TREE_OFF_NODE_OFFSET_ROOT  = 24;
static constexpr uint32_t TREE_OFF_NODE_COUNT_LEAF   = 32;
static constexpr uint32_t TREE_OFF_NODE_COUNT_LOWER  = 36;
static constexpr uint32_t TREE_OFF_NODE_COUNT_UPPER  = 40;
static constexpr uint32_t TREE_OFF_VOXEL_COUNT       = 56;

/// The smallest possible grid: GridData + TreeData
static constexpr uint32_t GRID_HEADER_SIZE = GRID_SIZE + TREE_SIZE;

// ---- Root, root tiles, internal nodes, leaves (the value-independent fields) --

static constexpr uint32_t ROOT_OFF_BBOX_MIN   = 0;   ///< int32[3]
static constexpr uint32_t ROOT_OFF_BBOX_MAX   = 12;  ///< int32[3], inclusive
static constexpr uint32_t ROOT_OFF_TABLE_SIZE = 24;  ///< uint32 tile count

static constexpr uint32_t ROOT_TILE_OFF_KEY   = 0;   ///< uint64, see coord_to_key
static constexpr uint32_t ROOT_TILE_OFF_CHILD = 8;   ///< int64 bytes, relative to the root
static constexpr uint32_t ROOT_TILE_OFF_STATE = 16;

static constexpr uint32_t UPPER_OFF_BBOX_MIN  = 0;
static constexpr uint32_t UPPER_OFF_VALUE_MASK = 32;
static constexpr uint32_t UPPER_OFF_CHILD_MASK = 4128;
static constexpr uint32_t LOWER_OFF_BBOX_MIN  = 0;
static constexpr uint32_t LOWER_OFF_VALUE_MASK = 32;
static constexpr uint32_t LOWER_OFF_CHILD_MASK = 544;
static constexpr uint32_t LEAF_OFF_BBOX_MIN   = 0;
static constexpr uint32_t LEAF_OFF_BBOX_DIF_AND_FLAGS = 12; ///< bbox dif (3 bytes), flags (top byte)
static constexpr uint32_t LEAF_OFF_VALUE_MASK = 16;

/// Quantized leaves (Fp4, Fp8, Fp16, FpN; PNANOVDB_LEAF_TABLE_NEG_OFF_*):
/// fields found by going back from the value table, in bytes. A value is
/// code * quantum + minimum; FpN keeps log2 of its bit width in flags >> 5.
static constexpr uint32_t LEAF_TABLE_NEG_OFF_BBOX_DIF_AND_FLAGS = 84;
static constexpr uint32_t LEAF_TABLE_NEG_OFF_MINIMUM = 16;
static constexpr uint32_t LEAF_TABLE_NEG_OFF_QUANTUM = 12;

// ---- Node geometry (NanoVDB's 5-4-3 tree) -----------------------------------------
// An upper node has 32^3 entries of 128^3 voxels, a lower node 16^3 entries
// of 8^3 voxels, a leaf 8^3 voxels. A root tile covers 4096^3 voxels.

static constexpr uint32_t UPPER_LOG2_DIM = 5, LOWER_LOG2_DIM = 4, LEAF_LOG2_DIM = 3;
static constexpr uint32_t UPPER_TABLE_COUNT = 1u << (3 * UPPER_LOG2_DIM); // 32768
static constexpr uint32_t LOWER_TABLE_COUNT = 1u << (3 * LOWER_LOG2_DIM); // 4096
static constexpr uint32_t LEAF_TABLE_COUNT  = 1u << (3 * LEAF_LOG2_DIM);  // 512
/// log2 of the voxels an entry of each level spans per axis: leaf voxel 0,
/// lower entry 3, upper entry 7, root tile 12
static constexpr uint32_t LOWER_ENTRY_LOG2 = LEAF_LOG2_DIM,
                          UPPER_ENTRY_LOG2 = LOWER_ENTRY_LOG2 + LOWER_LOG2_DIM,
                          ROOT_TILE_LOG2   = UPPER_ENTRY_LOG2 + UPPER_LOG2_DIM;

/// NANOVDB_DATA_ALIGNMENT: every node starts 32-byte aligned within the grid
/// and every node size is a multiple of 32
static constexpr uint32_t NODE_ALIGNMENT = 32;

// ---- Per value type: pnanovdb_grid_type_constants_t ------------------------------

/// PNanoVDB: pnanovdb_grid_type_constants_t (the fields in its order)
struct GridTypeConstants {
    uint32_t root_off_background, root_off_min, root_off_max, root_off_ave,
             root_off_stddev, root_size, value_stride_bits, table_stride,
             root_tile_off_value, root_tile_size, upper_off_min, upper_off_max,
             upper_off_ave, upper_off_stddev, upper_off_table, upper_size,
             lower_off_min, lower_off_max, lower_off_ave, lower_off_stddev,
             lower_off_table, lower_size, leaf_off_min, leaf_off_max,
             leaf_off_ave, leaf_off_stddev, leaf_off_table, leaf_size;
};

/// PNanoVDB: pnanovdb_grid_type_constants[PNANOVDB_GRID_TYPE_FLOAT]
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FLOAT = {
    28, 32, 36, 40, 44, 64, 32, 8, 20, 32,
    8224, 8228, 8232, 8236, 8256, 270400,
    1056, 1060, 1064, 1068, 1088, 33856,
    80, 84, 88, 92, 96, 2144
};
/// ... [PNANOVDB_GRID_TYPE_VEC3F]: 3 floats per value, 16-byte table entries
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_VEC3F = {
    28, 40, 52, 64, 68, 96, 96, 16, 20, 32,
    8224, 8236, 8248, 8252, 8256, 532544,
    1056, 1068, 1080, 1084, 1088, 66624,
    80, 92, 104, 108, 128, 6272
};
/// ... [PNANOVDB_GRID_TYPE_HALF]: IEEE binary16 everywhere (tiles too)
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_HALF = {
    28, 30, 32, 36, 40, 64, 16, 8, 20, 32,
    8224, 8226, 8228, 8232, 8256, 270400,
    1056, 1058, 1060, 1064, 1088, 33856,
    80, 82, 84, 88, 96, 1120
};
/// ... [PNANOVDB_GRID_TYPE_FP4 / FP8 / FP16 / FPN]: float tiles; leaves hold
/// minimum, quantum and packed codes (value_stride_bits 0: the table address
/// is the table's start, the reader finds the code). FpN's leaf_size is the
/// leaf without its table: FpN leaves differ in size (fpn_leaf_size()).
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FP4 = {
    28, 32, 36, 40, 44, 64, 0, 8, 20, 32,
    8224, 8228, 8232, 8236, 8256, 270400,
    1056, 1060, 1064, 1068, 1088, 33856,
    88, 90, 92, 94, 96, 352
};
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FP8 = [] {
    GridTypeConstants c = GRID_TYPE_CONSTANTS_FP4; c.leaf_size = 608; return c; }();
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FP16 = [] {
    GridTypeConstants c = GRID_TYPE_CONSTANTS_FP4; c.leaf_size = 1120; return c; }();
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_FPN = [] {
    GridTypeConstants c = GRID_TYPE_CONSTANTS_FP4; c.leaf_size = 96; return c; }();

/// ... [PNANOVDB_GRID_TYPE_ONINDEX] (PNanoVDB 32.6): 64-bit value indices
/// (the background, stats and tiles); a leaf holds no values, only its mask,
/// the index of its first active voxel (u64 at leaf_off_table) and the
/// prefix sums of its mask's popcounts (u64 after it: seven 9-bit fields)
static constexpr GridTypeConstants GRID_TYPE_CONSTANTS_ONINDEX = {
    32, 40, 48, 56, 64, 96, 0, 8, 24, 32,
    8224, 8232, 8240, 8248, 8256, 270400,
    1056, 1064, 1072, 1080, 1088, 33856,
    80, 80, 80, 80, 80, 96
};
/// Bytes from an OnIndex leaf's table to its prefix sums
static constexpr uint32_t ONINDEX_LEAF_TABLE_OFF_PREFIX_SUM = 8;

/// How a type's values are stored (what PNanoVDB's per-type read functions
/// encode in their names)
enum class LeafCodec : uint32_t {
    Float32, ///< float: 32-bit floats everywhere
    Half,    ///< binary16 everywhere
    Fixed,   ///< Fp4/Fp8/Fp16: float tiles, leaves of 2^log2_bits-bit codes
    FpN,     ///< as Fixed, the bit width per leaf (flags >> 5)
    Vec3f,   ///< 3 floats everywhere
    OnIndex  ///< value indices everywhere; the values in a separate array
};

/// What the loader and the lookups need to know about a supported type
struct ValueType {
    uint32_t grid_type;
    const char *name;              ///< as the loader's grid_type_name() spells it
    const GridTypeConstants *constants;
    LeafCodec codec;
    uint32_t log2_bits;            ///< Fixed: log2 of the code width (2, 3, 4)
    uint32_t channels;             ///< 1, or 3 for Vec3f
};

static constexpr ValueType VALUE_TYPES[] = {
    { GRID_TYPE_FLOAT, "float", &GRID_TYPE_CONSTANTS_FLOAT, LeafCodec::Float32, 5, 1 },
    { GRID_TYPE_HALF,  "Half",  &GRID_TYPE_CONSTANTS_HALF,  LeafCodec::Half,    4, 1 },
    { GRID_TYPE_FP4,   "Fp4",   &GRID_TYPE_CONSTANTS_FP4,   LeafCodec::Fixed,   2, 1 },
    { GRID_TYPE_FP8,   "Fp8",   &GRID_TYPE_CONSTANTS_FP8,   LeafCodec::Fixed,   3, 1 },
    { GRID_TYPE_FP16,  "Fp16",  &GRID_TYPE_CONSTANTS_FP16,  LeafCodec::Fixed,   4, 1 },
    { GRID_TYPE_FPN,   "FpN",   &GRID_TYPE_CONSTANTS_FPN,   LeafCodec::FpN,     0, 1 },
    { GRID_TYPE_VEC3F, "Vec3f", &GRID_TYPE_CONSTANTS_VEC3F, LeafCodec::Vec3f,   5, 3 },
    { GRID_TYPE_ONINDEX, "OnIndex", &GRID_TYPE_CONSTANTS_ONINDEX, LeafCodec::OnIndex, 0, 1 },
};

/// The supported type `grid_type`, or nullptr
constexpr const ValueType *value_type(uint32_t grid_type) {
    for (const ValueType &t : VALUE_TYPES)
        if (t.grid_type == grid_type)
            return &t;
    return nullptr;
}

/// The row of a grid type, at compile time (device code)
template <uint32_t GridType> struct grid_type_traits {
    static constexpr const ValueType &type = *value_type(GridType);
    static constexpr const GridTypeConstants &constants = *type.constants;
};

/// The row of a grid type, at run time (host code); nullptr: not supported
constexpr const GridTypeConstants *grid_type_constants(uint32_t grid_type) {
    const ValueType *t = value_type(grid_type);
    return t ? t->constants : nullptr;
}

/**
 * Calls fn(std::integral_constant<uint32_t, T>{}) with the supported type T
 * that `grid_type` names (float for any other value): the one place where a
 * run-time grid type becomes a compile-time one. Every type is compiled, one
 * is called. WithVec3f = false leaves Vec3f out (it becomes float), for code
 * that reads scalar values only.
 */
template <bool WithVec3f = true, typename Fn>
decltype(auto) visit_value_type(uint32_t grid_type, Fn &&fn) {
    using std::integral_constant;
    switch (grid_type) {
        case GRID_TYPE_HALF: return fn(integral_constant<uint32_t, GRID_TYPE_HALF>{});
        case GRID_TYPE_FP4:  return fn(integral_constant<uint32_t, GRID_TYPE_FP4>{});
        case GRID_TYPE_FP8:  return fn(integral_constant<uint32_t, GRID_TYPE_FP8>{});
        case GRID_TYPE_FP16: return fn(integral_constant<uint32_t, GRID_TYPE_FP16>{});
        case GRID_TYPE_FPN:  return fn(integral_constant<uint32_t, GRID_TYPE_FPN>{});
        case GRID_TYPE_ONINDEX: return fn(integral_constant<uint32_t, GRID_TYPE_ONINDEX>{});
        case GRID_TYPE_VEC3F:
            if constexpr (WithVec3f)
                return fn(integral_constant<uint32_t, GRID_TYPE_VEC3F>{});
            else
                return fn(integral_constant<uint32_t, GRID_TYPE_FLOAT>{});
        default:             return fn(integral_constant<uint32_t, GRID_TYPE_FLOAT>{});
    }
}

/// Bytes of an FpN leaf whose flags byte is `flags`: the header and 512
/// codes of 1 << (flags >> 5) bits (1 to 16; widths past 16 are invalid)
constexpr uint32_t fpn_leaf_size(uint32_t flags) {
    return GRID_TYPE_CONSTANTS_FPN.leaf_off_table + (64u << (flags >> 5));
}
/// The smallest FpN leaf (1-bit codes): the stride of its majorant slots
static constexpr uint32_t FPN_MIN_LEAF_SIZE = 96 + 64;

// The tables fill their nodes exactly, and every node keeps the alignment
constexpr bool fills_nodes(const GridTypeConstants &c, uint32_t leaf_value_bits) {
    return c.upper_off_table + UPPER_TABLE_COUNT * c.table_stride == c.upper_size &&
           c.lower_off_table + LOWER_TABLE_COUNT * c.table_stride == c.lower_size &&
           c.leaf_off_table + LEAF_TABLE_COUNT * leaf_value_bits / 8 == c.leaf_size &&
           c.upper_size % NODE_ALIGNMENT == 0 && c.lower_size % NODE_ALIGNMENT == 0 &&
           c.leaf_size % NODE_ALIGNMENT == 0 && c.root_size % NODE_ALIGNMENT == 0 &&
           c.root_tile_size % NODE_ALIGNMENT == 0;
}
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_FLOAT, 32));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_VEC3F, 96));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_HALF, 16));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_FP4, 4));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_FP8, 8));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_FP16, 16));
static_assert(fills_nodes(GRID_TYPE_CONSTANTS_FPN, 0));
// OnIndex: internal nodes as float's (8-byte entries); a leaf's "table" is
// its first index and its prefix sums, 16 bytes
static_assert(GRID_TYPE_CONSTANTS_ONINDEX.leaf_off_table + 16 == GRID_TYPE_CONSTANTS_ONINDEX.leaf_size &&
              GRID_TYPE_CONSTANTS_ONINDEX.upper_off_table == GRID_TYPE_CONSTANTS_FLOAT.upper_off_table &&
              GRID_TYPE_CONSTANTS_ONINDEX.lower_off_table == GRID_TYPE_CONSTANTS_FLOAT.lower_off_table &&
              GRID_TYPE_CONSTANTS_ONINDEX.upper_size == GRID_TYPE_CONSTANTS_FLOAT.upper_size &&
              GRID_TYPE_CONSTANTS_ONINDEX.lower_size == GRID_TYPE_CONSTANTS_FLOAT.lower_size &&
              GRID_TYPE_CONSTANTS_ONINDEX.root_size % NODE_ALIGNMENT == 0);
static_assert(fpn_leaf_size(0) == FPN_MIN_LEAF_SIZE && fpn_leaf_size(4u << 5) == 1120);

// ---- Root keys (host side; the device computes keys in pnanovdb.h) ----------------

/// The inverse of PNanoVDB's pnanovdb_coord_to_key: the 4096^3 block (ijk >> 12,
/// arithmetic shift) whose root tile has this key. Keys pack three 21-bit
/// fields, x in the top bits; each is the block coordinate's low 20 bits
/// (sign-extended here).
inline void key_to_block(uint64_t key, int32_t block[3]) {
    for (int axis = 0; axis < 3; ++axis) {
        uint32_t field = uint32_t((key >> (21 * (2 - axis))) & 0x1FFFFFu);
        block[axis] = int32_t(field << 12) >> 12;
    }
}

/// The first voxel of the block of key_to_block(key) (ijk with low 12 bits 0)
inline void key_to_origin(uint64_t key, int32_t origin[3]) {
    for (int axis = 0; axis < 3; ++axis)
        origin[axis] =
            int32_t(uint32_t((key >> (21 * (2 - axis))) & 0x1FFFFFu) << ROOT_TILE_LOG2);
}

} // namespace nanovdb_drjit::layout
