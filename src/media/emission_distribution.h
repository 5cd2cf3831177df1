/*
    src/media/emission_distribution.h -- an emissive medium's emission as a
    distribution of points, for next-event estimation (issue 35)

    The medium evaluates what each voxel of its emission grid emits (the
    largest channel of sigma_a Le at the voxel's centre, times its volume)
    at every voxel of the grid's leaves, in one vectorized call on the
    backend; the host builds the table from those weights
    (nanovdb_loader/emission_table.h: 2^3 blocks per leaf at 4 bits, a CDF
    over the leaves and tiles); the table goes to the backend, where
    nanovdb_drjit/emission_sampling.h samples it. The emission volume says
    where its leaves and tiles are (nanovdb_mitsuba/grid_units.h).

    sample() returns a world point and its pdf per unit world volume;
    pdf() recomputes it for any point (MIS): the same table words and the
    same arithmetic, so the two agree exactly for a sampled point. Active
    tiles of the emission grid are units too (one weight each, at the
    tile's centre; a point uniform in the tile). Points in no leaf or
    active tile, or in a block of weight 0, have pdf 0: the filter's reach
    (trilinear and stochastic filters read neighbours) or an inactive tile
    can make them emit, and the collision estimator, weighted 1 there by
    MIS, covers them.
*/

#pragma once

#include <mitsuba/core/logger.h>
#include <mitsuba/core/vector.h>

#include <nanovdb_drjit/emission_sampling.h>
#include <nanovdb_drjit/traverse.h>
#include <nanovdb_loader/emission_table.h>
#include <nanovdb_mitsuba/grid_units.h>

#include <chrono>
#include <string>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

template <typename Float, typename Spectrum> class EmissionDistribution {
public:
    MI_IMPORT_CORE_TYPES()
    using Units = GridUnits<Float, Spectrum>;
    using Table = std::conditional_t<dr::is_jit_v<Float>, UInt32, std::vector<uint32_t>>;

    /// Whether a table was built (build() succeeded)
    bool valid() const { return m_unit_count > 0; }

    /// What the table holds, in the weights' units (the medium's emitted
    /// power, up to the constant of its largest channel)
    double power() const { return m_power; }
    size_t bytes() const { return m_bytes; }
    double build_seconds() const { return m_seconds; }

    /**
     * Builds the table over `units`' leaves with `weight(p, active)`, what a
     * point emits per unit volume (>= 0). Returns "" or why there is no
     * table (no addressable leaves, zero power, a bad weight); the caller
     * names the file and says what it does instead.
     */
    template <typename WeightFn> std::string build(const Units *units, WeightFn &&weight) {
        auto t0 = std::chrono::steady_clock::now();
        *this = EmissionDistribution();
        const uint32_t leaves = units ? units->unit_leaf_count() : 0,
                       tiles = units ? units->unit_tile_count() : 0;
        if (leaves + tiles == 0)
            return "its grid has no leaves or active tiles it can sample: it is an FpN grid "
                   "or a 6-channel volume";
        const size_t n = size_t(leaves) * 512;
        const ScalarFloat voxel = units->voxel_volume();
        // Weights: each leaf voxel's at its centre, each tile's at its
        // centre times its voxels (a tile holds one value; a filter's reach
        // into its neighbours is the collision estimator's: MIS)
        std::vector<float> w(n), wt(tiles);
        if constexpr (dr::is_jit_v<Float>) {
            auto fetch = [&](std::vector<float> &out, const Float &v) {
                if (out.empty())
                    return;
                dr::eval(v);
                dr::sync_thread();
                dr::store(out.data(), v);
            };
            if (n) {
                UInt32 i = dr::arange<UInt32>((uint32_t) n);
                Point3f p = units->leaf_voxel_point(i >> 9, i & 511u, true);
                fetch(w, dr::detach(weight(p, Mask(true))) * voxel);
            }
            if (tiles) {
                auto [p, voxels] = units->tile_point(dr::arange<UInt32>(tiles), Point3f(.5f),
                                                     true);
                fetch(wt, dr::detach(weight(p, Mask(true))) * voxel * voxels);
            }
        } else {
            for (size_t i = 0; i < n; ++i)
                w[i] = weight(units->leaf_voxel_point(uint32_t(i >> 9), uint32_t(i & 511), true),
                              true) * voxel;
            for (uint32_t t = 0; t < tiles; ++t) {
                auto [p, voxels] = units->tile_point(t, Point3f(.5f), true);
                wt[t] = weight(p, true) * voxel * voxels;
            }
        }
        nanovdb_loader::EmissionTable t;
        try {
            t = nanovdb_loader::build_emission_table(w, wt);
        } catch (const std::invalid_argument &e) {
            return e.what();
        }
        m_units = units;
        m_leaves = t.leaf_count;
        m_unit_count = t.leaf_count + t.tile_count;
        m_power = t.total;
        m_bytes = t.bytes();
        m_block_volume = 8.f * voxel;
        m_voxel_volume = voxel;
        if constexpr (dr::is_jit_v<Float>)
            m_table = dr::load<UInt32>(t.words.data(), t.words.size());
        else
            m_table = std::move(t.words);
        m_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        return "";
    }

    /// A point in proportion to the weights (u, u3 uniform), and its pdf per
    /// unit world volume
    std::pair<Point3f, Float> sample(const Float &u, const Point3f &u3, Mask active) const {
        auto pick =
            nanovdb_drjit::sample_emission<UInt32>(words(), m_unit_count, m_leaves, u, active);
        Point3f p = m_units->leaf_block_point(pick.unit, pick.block, u3,
                                              active && pick.unit < m_leaves);
        Float volume = m_block_volume;
        if (m_unit_count > m_leaves) { // (a tile: uniform in its box)
            Mask tile = active && pick.unit >= m_leaves;
            auto [pt, voxels] = m_units->tile_point(pick.unit - m_leaves, u3, tile);
            dr::masked(p, tile) = pt;
            dr::masked(volume, tile) = voxels * m_voxel_volume;
        }
        return { p, pick.prob / volume };
    }

    /// The pdf per unit world volume that sample() gives the point p (0
    /// where no leaf or active tile, or a block of weight 0, holds it)
    Float pdf(const Point3f &p, Mask active) const {
        auto [unit, block, found] = m_units->locate_unit(p, active);
        Float prob = nanovdb_drjit::emission_probability<UInt32>(words(), m_unit_count, m_leaves,
                                                                 unit, block, active && found);
        Float volume = m_block_volume;
        if (m_unit_count > m_leaves) {
            Mask tile = active && found && unit >= m_leaves;
            dr::masked(volume, tile) =
                m_units->tile_point(unit - m_leaves, Point3f(.5f), tile).second * m_voxel_volume;
        }
        return dr::select(active && found, prob / volume, 0.f);
    }

    /// Its table, for Dr.Jit's traversal (a frozen function's inputs)
    NVDB_TRAVERSE(m_table)

private:
    decltype(auto) words() const {
        if constexpr (dr::is_jit_v<Float>)
            return (const UInt32 &) m_table;
        else
            return static_cast<const uint32_t *>(m_table.data());
    }

    const Units *m_units = nullptr;
    uint32_t m_leaves = 0, m_unit_count = 0; ///< the table's leaves; its units (leaves, tiles)
    Table m_table;
    ScalarFloat m_block_volume = 0.f, m_voxel_volume = 0.f;
    double m_power = 0.0, m_seconds = 0.0;
    size_t m_bytes = 0;
};

NAMESPACE_END(mitsuba)
