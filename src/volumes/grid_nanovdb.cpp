#include <mitsuba/core/fresolver.h>
#include <mitsuba/core/properties.h>
#include <mitsuba/core/string.h>
#include <mitsuba/core/transform.h>
#include <mitsuba/render/srgb.h>
#include <mitsuba/render/volume.h>

#include <nanovdb_drjit/emission_sampling.h>
#include <nanovdb_drjit/sampler.h>
#include <nanovdb_loader/load.h>
#include <nanovdb_loader/majorants.h>
#include <nanovdb_loader/vdb_import.h>
#include <nanovdb_mitsuba/volume_source.h>
#include <nanovdb_mitsuba/frozen.h>
#include <nanovdb_mitsuba/grid_units.h>
#include <nanovdb_mitsuba/local_majorants.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include "memory_source.h"
#include "grid_load.h"
#include "volume_properties.h"
#include "index_updates.h"
#include "placement.h"
#include "sampler_setup.h"

#include <array>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <memory>
#include <vector>

// The lookups are compiled once per backend, in sampler_*.cpp
extern template class nanovdb_drjit::GridSampler<float>;
extern template class nanovdb_drjit::GridSampler<drjit::DiffArray<JitBackend::LLVM, float>>;
extern template class nanovdb_drjit::GridSampler<drjit::DiffArray<JitBackend::CUDA, float>>;

NAMESPACE_BEGIN(mitsuba)

/**!

.. _volume-nanovdbvolume:

NanoVDB sparse volume (:monosp:`nanovdbvolume`)
-----------------------------------------------

.. pluginparameters::

 * - filename
   - |string|
   - Path of the file to load. A NanoVDB file (``.nvdb``): files written by
     NanoVDB 32.3 to 32.9 (OpenVDB 10 to 13) are read, uncompressed or with
     the ZIP or BLOSC codec, including files with several grids or segments
     and raw grid buffers. An OpenVDB file (``.vdb``): only the chosen grid
     is read and converted as ``vdb2nvdb`` converts it, in a separate
     process (``nanovdb-vdb-reader``) under a memory budget and a deadline,
     so that a damaged file is an error that says so, never a crash of the
     process that loads it. A Mitsuba grid file (``.vol``), as
     ``gridvolume`` reads it.

 * - grid
   - |string|
   - Which grid of the file to use: its name, or its index in the file
     (``"0"``, ``"1"``, ...) when no grid has that name. Only that grid's
     bytes are read. Types: float, Half, Fp4, Fp8, Fp16, FpN (one channel)
     and Vec3f (three). (Default: the first grid of one of these types)

 * - grid
   - :monosp:`VolumeGrid object`
   - Instead of a file, as for ``gridvolume``: its values, made into a sparse
     grid in memory (voxels equal to the background left out).

 * - data
   - |tensor|
   - Instead of a file, as for ``gridvolume``: a tensor of shape (z, y, x)
     or (z, y, x, channels), 1, 3 or 6 channels, made into a sparse grid.
     With ``differentiable=true`` the values of a 1- or 3-channel volume
     (from any source) are exposed as the differentiable parameter ``data``
     (see ``differentiable``); a 6-channel volume refuses
     ``differentiable=true``.
   - |exposed|, |differentiable|

 * - values, coords
   - |tensor|
   - Instead of a file: voxels one by one, a TensorXf of shape (n,) or (n, 3)
     and a TensorXi of shape (n, 3) (index coordinates x, y, z).

 * - background
   - |float|
   - Volumes from memory: the value outside the active voxels. (Default: 0)

 * - threshold
   - |float|
   - Volumes from memory: values within this distance of the background are
     left out too (lossy). (Default: 0)

 * - filter_type
   - |string|
   - ``trilinear``: interpolate between voxel centres, as NanoVDB's own
     trilinear sampler does; ``nearest``: the value of the voxel that
     contains the point; ``stochastic_trilinear``: one voxel read, drawn at
     random so that its expected value is the trilinear one (Pharr et al.,
     "Filtering After Shading with Stochastic Texture Filtering", 2024);
     ``stochastic_tricubic``: the same for the cubic B-spline, a smoother
     filter that reaches 1.5 voxels. Stochastic filters keep every tracking
     estimator unbiased for the filtered medium (its density enters them
     linearly), at one read instead of 8; they add noise per sample.
     ``volpathlocal`` draws their offsets from its sampler; other
     integrators call ``eval()``, which has no sampler, so the offsets come
     from a hash of the lookup position and a seed per volume: the same
     point always reads the same voxel (a fixed, finely dithered medium
     whose average over any sub-voxel region is the filtered one), and two
     volumes of one medium (density, albedo) are dithered independently.
     (Default: ``trilinear``)

 * - use_grid_transform
   - |bool|
   - If ``false``, the volume's local unit cube :math:`[0, 1]^3` spans the
     grid's active voxels exactly as ``gridvolume`` spans a dense array of the
     same box, so the two plugins render the same image under the same
     ``to_world``. If ``true``, local space is the grid's own world space
     (its index-to-world map from the file), so the volume lines up with
     other VDB tools. (Default: ``false``)

 * - wrap_mode
   - |string|
   - What lookups read outside the volume's box: ``tree``, the tree's own
     values (VDB semantics); ``clamp``, the nearest edge voxel
     (``gridvolume``'s convention). (Default: ``clamp`` for ``data`` and a
     VolumeGrid, ``tree`` otherwise)

 * - use_grid_bbox
   - |bool|
   - As ``gridvolume``'s: the unit cube maps to the values' world box (a
     VolumeGrid's bbox; a file's voxels through its grid transform).
     (Default: ``false``)

 * - max_value
   - |float|
   - As ``gridvolume``'s: a bound given by the user; used as ``max()`` when
     it is larger than the values' own, ignored with a warning otherwise.

 * - accel
   - |bool|
   - Accepted for ``gridvolume`` scenes, no effect (no texture units: the
     tree is traversed).

 * - raw
   - |bool|
   - Vec3f grids in spectral variants: ``false`` turns the colours into
     spectra (``eval()``); ``true`` keeps the raw vectors (``eval_3()``), as
     ``gridvolume``'s ``raw``. (Default: ``false``)

 * - differentiable
   - |bool|
   - ``true``: the grid (float, Half, quantized or Vec3f) becomes an index
     grid (NanoVDB's OnIndex: its tree, with value indices) and one Float
     array of its active voxels' and tiles' values, exposed as the
     differentiable parameter ``data`` (nanovdb_loader/index_grid.h gives
     the order; a Vec3f grid's three channels interleaved: value i at
     ``data[3 i .. 3 i + 2]``; in spectral variants only with
     ``raw=true``). After ``params.update()``, ``max()`` follows the
     values, and so do the per-node majorants that ``volpathlocal`` and
     ``prbvolpathlocal`` track with (see ``majorant_rebuild``).
     (Default: ``false``)

 * - majorant_rebuild
   - |string|
   - Where the per-node majorants of a differentiable volume are rebuilt
     after ``params.update()`` changed its values, when a walk next asks
     for them: ``backend``, on the variant's backend (LLVM, CUDA) from a
     plan of the tree made at load, with no copy of the values to the
     host; ``host``, on the host through the loader's own passes (what
     scalar variants, and a tree the plan cannot take, do). The two build
     the same table. ``max()`` after an update is the values' largest
     (with the background and ``max_value``); ``host`` also narrows it to
     the lookups of the volume's box. (Default: ``backend``)

 * - blind_channel, blind_component
   - |string|, |int|
   - Index grids of a file (OnIndex, e.g. fVDB's and Warp's): the blind
     channel holding the values (default: the first channel of floats) and,
     where each value has several floats (fVDB's tensor rows), which one
     (default: 0). Their values are exposed as ``data`` too.

 * - invalid_values
   - |string|
   - What to do with NaN, infinite and negative voxel or tile values:
     ``error``: refuse a grid with NaN or infinite values, naming the first
     offending voxel (negative values load, with a warning);
     ``clamp``: replace NaN by 0, +Inf by the largest finite value of the
     grid, -Inf and negative values by 0, with a warning that counts them.
     (Default: ``error``)

 * - level_set
   - |string|
   - What a file's level set grid (signed distances) becomes: ``fog``, a
     fog volume as ``vdb2nvdb`` makes one (OpenVDB's ``sdfToFogVolume``: 0
     outside, rising through the narrow band to 1 inside), read in the
     ``.vdb`` reader process, for ``.nvdb`` files too; ``distance``, the
     distances as stored. Other grids are read as they are. (Default:
     ``fog`` for a ``.vdb`` file, ``distance`` for a ``.nvdb`` file)

 * - to_world
   - |transform|
   - Transformation applied to the volume's local space. (Default: identity)

 * - count_lookups
   - |bool|
   - A benchmarking aid: count the lookups (``eval*`` calls, per lane) and
     the cells majorant walks enter (see the ``volpathlocal`` integrator),
     at the cost of an atomic add each; ``to_string()`` reports the counts
     (``lookup_count``, ``walk_step_count``, the steps by cell: empty, 8,
     32, 128 and 4096 voxels wide, and ``walk_count``, the walks begun).
     (Default: ``false``)

This plugin renders sparse volumes stored as NanoVDB grids directly, without
a dense conversion: a cloud that needs hundreds of megabytes as a dense
``gridvolume`` stays at the size of its ``.nvdb`` file, in CPU and GPU memory
alike. It works in every variant (``scalar_*``, ``llvm_ad_*``, ``cuda_ad_*``;
RGB, monochrome, spectral and polarized), where it behaves like a
single-channel ``gridvolume`` (Vec3f grids: a 3-channel one, see ``raw``).

Lookups traverse the NanoVDB tree (root, upper, lower and leaf nodes) with a
Dr.Jit translation of PNanoVDB (``nanovdb_drjit/sampler.h``). With
``wrap_mode="tree"`` values outside the active voxels are whatever the tree
stores there -- normally the grid's background value (VDB semantics), so
``trilinear`` interpolation in the outer half voxel of the active box blends
towards the background; with ``wrap_mode="clamp"`` lookups read the nearest
edge voxel, as ``gridvolume`` does.

Coordinates, with ``use_grid_transform=false``: if the grid's active voxels
span the inclusive index box :math:`[m, M]` and :math:`d = M - m + 1`, the
local point :math:`u \in [0, 1]^3` reads voxel :math:`\lfloor m + u d
\rfloor` (``nearest``) or interpolates at the index position :math:`m + u d
- 0.5` (``trilinear``). Positions are computed relative to :math:`m` in
floating point, and the integer :math:`m` is added last, so grids far from
the origin keep full precision.

The file is validated once when it is loaded (every node offset of the tree
must point inside it), so lookups can trust it. ``max()`` is the largest
value a lookup inside the volume can return: the voxels and tiles of the
active index box, for ``trilinear`` also the one-voxel ring its stencils
reach (and the background where they leave the tree). Values the grid
stores elsewhere do not count: a fog volume made from a level set often
keeps the level set's background in its root, and a global maximum would
make the ``heterogeneous`` medium's majorant (``scale * max()``) several
times too large. Every lookup is clamped to ``max()``, so it is a true upper
bound even at points outside the box (and for the few ulps by which rounded
trilinear weights can overshoot the largest corner). Grids containing
NaN or infinite values are rejected unless ``invalid_values="clamp"``.

Value types: quantized grids (Fp4, Fp8, Fp16, FpN) and Half grids are decoded
in the lookup, as PNanoVDB decodes them, and never expanded: the backend
holds their bytes. A Vec3f grid is a 3-channel volume that behaves like
``gridvolume`` on a 3-channel ``.vol`` of the same box: ``eval_3()`` the
vector, ``eval()`` the colour (RGB), its luminance (monochrome) or its
sRGB-model spectrum (spectral: each voxel's colour becomes coefficients in
place and a scale beside the grid, one float per leaf voxel), ``eval_1()``
the luminance, ``max_per_channel()`` each channel's ``max()``. A 6-channel
volume (the SGGX phase function's ``S``) is two Vec3f grids: from 6-channel
``data``, or from a file's pair of grids named ``X[0:3]`` and ``X[3:6]``
(``grid="X"``); ``eval_6()`` and ``eval_n()`` read both. Other grid types
(double, int, index, points, masks) fail with a message that names the type
and lists the supported ones.

.. tabs::
    .. code-tab:: xml

        <medium type="heterogeneous">
            <volume type="nanovdbvolume" name="sigma_t">
                <string name="filename" value="cloud.nvdb"/>
                <string name="grid" value="density"/>
            </volume>
        </medium>

    .. code-tab:: python

        'type': 'heterogeneous',
        'sigma_t': {
            'type': 'nanovdbvolume',
            'filename': 'cloud.nvdb',
            'grid': 'density'
        }
*/

using nvdb::Filter;
using nvdb::FILTER_NAMES;

template <typename Float, typename Spectrum>
class NanoVDBVolume final : public Volume<Float, Spectrum>,
                            public LocalMajorants<Float, Spectrum>,
                            public GridUnits<Float, Spectrum>,
                            public nanovdb_mitsuba::VolumeSource {
public:
    MI_IMPORT_BASE(Volume, update_bbox, m_to_local, m_bbox, m_channel_count)
    MI_IMPORT_TYPES()
    using Walk = typename LocalMajorants<Float, Spectrum>::Walk;
    using WalkRay = typename LocalMajorants<Float, Spectrum>::WalkRay;
    using Sampler = nanovdb_drjit::GridSampler<Float>;
    using Array3f = dr::Array<Float, 3>;

    NanoVDBVolume(const Properties &props) : Base(props) {
        // The properties (volume_properties.h); values from memory are read
        // there (memory_source.h) and built into a grid here
        // (nanovdb_loader/build.h)
        std::optional<MemorySource<Float, Spectrum>> memory;
        const nvdb::VolumeProperties p = nvdb::read_volume_properties(props, memory);
        m_filename = p.filename;
        m_filter = p.filter;
        m_clamp = p.clamp;
        m_use_grid_transform = p.use_grid_transform;
        m_load.settings = p.load;

        // The grid (a second one for 6 channels: channels 3 to 5)
        nanovdb_loader::GridSummary summary;
        std::optional<nanovdb_loader::IndexBox> box; // the volume's box, if not the active one
        if (!memory)
            summary = nanovdb_loader::is_vdb_path(m_filename)
                          ? m_load.vdb_file(p.selector, m_sampler)
                          : m_load.nvdb_file(p.selector, m_sampler, m_second);
        else
            summary = m_load.built(*memory, p.build, m_sampler, m_second, box);
        m_channel_count = m_second ? 6
                          : m_load.facts.grid_type == kVec3f || m_sampler.index_channels == 3 ? 3
                                                                                          : 1;
        if (m_load.settings.differentiable && m_channel_count == 6)
            Throw("nanovdbvolume: \"%s\": differentiable=true is not supported for a 6-channel "
                  "volume (its values are two grids of 3 channels, not one index grid); use "
                  "two 3-channel volumes, or leave differentiable out", m_filename);
        m_grid_name = m_load.facts.name;
        m_leaf_count = summary.node_count[0];
        set_tiles(std::move(m_load.tiles));
        // Stochastic filters' offsets in eval(): a hash of the position and
        // of this seed, so that volumes of other files or grids (a medium's
        // density and albedo) are dithered independently, and a scene
        // renders the same on every run
        m_seed = (uint32_t) std::hash<std::string>()(m_filename + '\n' + m_grid_name +
                                                      '\n' + std::to_string(m_channel_count));
        set_index_box(summary, box);
        if (m_second)
            m_second->set_box(m_index_min_box, m_resolution_box, kVec3f, m_clamp);
        if (p.use_grid_bbox)
            place_by_grid_bbox(summary, memory ? memory->bbox_transform : std::nullopt);
        if (m_use_grid_transform)
            set_grid_transform(summary);
        set_cell_transform();

        // gridvolume's max_value: a bound given by the user. A larger one
        // than the values' own is kept (a looser majorant: slower, still
        // unbiased); a smaller one would bias every render, so it is refused
        // with a warning, and the values' own is kept.
        if (p.max_value) {
            ScalarFloat given = *p.max_value;
            if (given >= max()) {
                m_load.index.max_value_given = given;
                m_load.facts.max = given;
                for (int k = 0; k < 3; ++k)
                    m_load.facts.max3[k] = std::max(m_load.facts.max3[k], given);
                m_sampler.set_bounds(m_load.facts.max, m_load.facts.max3);
            } else {
                Log(Warn, "nanovdbvolume: \"%s\": max_value = %f is below the largest value "
                          "lookups return (%f): a majorant that small would bias renders, "
                          "so max() stays %f", m_filename, given, max(), max());
            }
        }
        if (p.count_lookups)
            m_sampler.enable_counters();
        if (m_load.index.active()) { // (what an update that changes nothing keeps)
            m_load.index.remember(m_sampler, m_load.facts.max, m_load.facts.max3);
            m_load.index.bounded.majorant_ratio = m_load.facts.majorant_ratio;
        }
        Log(Debug, "Loaded \"%s\" grid \"%s\": index box [%s, %s + %s), %zu bytes, max %f",
            m_filename, m_grid_name, m_index_min_host, m_index_min_host, m_resolution_host,
            m_load.facts.grid_bytes, max());
    }

    // =====================================================================
    //  Volume interface: positions to index space (index_position()), then
    //  the sampler (nanovdb_drjit/sampler.h)
    // =====================================================================

    // Vec3f grids behave like a 3-channel gridvolume: eval() is the colour
    // (RGB), its luminance (monochrome) or its sRGB-model spectrum
    // (spectral; raw=true refuses, as gridvolume does); eval_1() the
    // luminance; eval_3() the raw vector (not in spectral variants unless raw).

    UnpolarizedSpectrum eval(const Interaction3f &it, Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 6)
            Throw("eval(): the nanovdbvolume \"%s\" has 6 channels: use eval_6()", m_filename);
        if (m_channel_count == 3 && is_spectral_v<Spectrum> && m_load.settings.raw)
            Throw("eval(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for a "
                  "spectrum, but its conversion into spectra was disabled (raw=true)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<UnpolarizedSpectrum>();
        if (m_channel_count == 1)
            return UnpolarizedSpectrum(lookup(it, active));
        if constexpr (is_monochromatic_v<Spectrum>)
            return UnpolarizedSpectrum(luminance(Color3f(lookup3(m_sampler, it, active))));
        else if constexpr (is_spectral_v<Spectrum>)
            return lookup_spectral(it, active);
        else
            return UnpolarizedSpectrum(lookup3(m_sampler, it, active));
    }

    Float eval_1(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 6)
            Throw("eval_1(): the nanovdbvolume \"%s\" has 6 channels: use eval_6()", m_filename);
        if (m_channel_count == 3 && is_spectral_v<Spectrum> && !m_load.settings.raw)
            Throw("eval_1(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for "
                  "a scalar value, but its conversion into spectra was requested (raw=false)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<Float>();
        if (m_channel_count == 3)
            return luminance(Color3f(lookup3(m_sampler, it, active)));
        return lookup(it, active);
    }

    void eval_n(const Interaction3f &it, Float *out, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 1) {
            out[0] = lookup(it, active);
            return;
        }
        Vector3f v = lookup3(m_sampler, it, active);
        for (int k = 0; k < 3; ++k)
            out[k] = v[k];
        if (m_second) {
            Vector3f w = lookup3(*m_second, it, active);
            for (int k = 0; k < 3; ++k)
                out[3 + k] = w[k];
        }
    }

    Vector3f eval_3(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count != 3)
            Throw("eval_3(): the nanovdbvolume \"%s\" (grid \"%s\") holds %s, not a 3D vector",
                  m_filename, m_grid_name, channels_str());
        if (is_spectral_v<Spectrum> && !m_load.settings.raw)
            Throw("eval_3(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for "
                  "a 3D vector, but its conversion into spectra was requested (raw=false)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<Vector3f>();
        return lookup3(m_sampler, it, active);
    }

    /// 6 channels: the two Vec3f grids, channels 0-2 and 3-5
    dr::Array<Float, 6> eval_6(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (!m_second)
            Throw("eval_6(): the nanovdbvolume \"%s\" (grid \"%s\") holds %s, not 6",
                  m_filename, m_grid_name, channels_str());
        dr::Array<Float, 6> out;
        if (dr::none_or<false>(active))
            return dr::zeros<dr::Array<Float, 6>>();
        Vector3f a = lookup3(m_sampler, it, active), b = lookup3(*m_second, it, active);
        for (int k = 0; k < 3; ++k) {
            out[k] = a[k];
            out[3 + k] = b[k];
        }
        return out;
    }

    ScalarFloat max() const override {
        return m_second ? std::max(m_load.facts.max, m_load.second_facts.max) : m_load.facts.max;
    }

    void max_per_channel(ScalarFloat *out) const override {
        if (m_channel_count == 1) {
            out[0] = m_load.facts.max;
            return;
        }
        for (int k = 0; k < 3; ++k) {
            out[k] = m_load.facts.max3[k];
            if (m_second)
                out[3 + k] = m_load.second_facts.max3[k];
        }
    }

    ScalarVector3i resolution() const override { return m_resolution_host; }

    /**
     * What the grid is, as non-differentiable parameters (Mitsuba's Python
     * side reads numbers, not strings: the grid type and class are NanoVDB's
     * codes; nanovdb_mitsuba.volume_facts() names them)
     */
    void traverse(TraversalCallback *cb) override {
        Base::traverse(cb);
        local_majorant_ratio(); // (its facts: an index grid's majorants after an update, their mean)
        m_trav.grid_type = m_load.facts.grid_type;
        m_trav.grid_class = m_load.facts.grid_class;
        m_trav.channels = m_channel_count;
        m_trav.bbox_min = m_bbox.min;
        m_trav.bbox_max = m_bbox.max;
        m_trav.max = max();
        m_trav.grid_bytes = double(m_load.facts.grid_bytes + m_load.second_facts.grid_bytes);
        m_trav.backend_bytes = double(backend_bytes());
        m_trav.majorant_bytes =
            double(m_load.facts.majorant_bytes + m_load.second_facts.majorant_bytes);
        m_trav.scale_bytes = double(m_load.facts.scale_bytes);
        auto put = [&](const char *name, auto &value) {
            cb->put(name, value, ParamFlags::NonDifferentiable);
        };
        put("grid_index", m_load.grid_index);
        put("grid_type", m_trav.grid_type);
        put("grid_class", m_trav.grid_class);
        put("channels", m_trav.channels);
        put("index_min", m_index_min_host);
        put("index_dims", m_resolution_host);
        put("world_bbox_min", m_trav.bbox_min);
        put("world_bbox_max", m_trav.bbox_max);
        put("max", m_trav.max);
        put("grid_max", m_load.facts.grid_max);
        put("background", m_background_host);
        put("local_majorant_ratio", m_load.facts.majorant_ratio);
        put("grid_bytes", m_trav.grid_bytes);
        put("backend_bytes", m_trav.backend_bytes);
        put("majorant_bytes", m_trav.majorant_bytes);
        put("spectral_scale_bytes", m_trav.scale_bytes);
        put("wrap_clamp", m_clamp);
        // differentiable: whether updates rebuild the majorants on the
        // backend (majorant_rebuild, and a tree the plan takes)
        m_trav.rebuild_on_backend = m_load.index.rebuild.valid();
        put("majorant_rebuild_on_backend", m_trav.rebuild_on_backend);
        m_trav.rebuild_replays = m_load.index.rebuild_replays();
        put("majorant_rebuild_replays", m_trav.rebuild_replays);
        // level_set="fog" made this grid, a level set in the file, a fog volume
        put("level_set_fogged", m_load.fogged);
        // A .vdb file: converted at load; the class the grid had in the file
        // (grid_class is what it became: a level set becomes a fog volume)
        put("vdb_imported", m_load.vdb.imported);
        if (m_load.vdb.imported) {
            put("vdb_source_class", m_load.vdb.source_class);
            put("vdb_fogged", m_load.fogged);
            put("vdb_convert_seconds", m_load.vdb.convert_seconds);
            // the reader process (nanovdb_loader/vdb_import.h): start to
            // reply, and its peak resident memory
            put("vdb_reader_seconds", m_load.vdb.reader_seconds);
            put("vdb_reader_peak_mb", m_load.vdb.reader_peak_mb);
        }
        m_trav.value_bytes = double(m_load.facts.value_bytes);
        put("value_bytes", m_trav.value_bytes);
        // An index grid's values (index i + 1 at i; index_grid.h gives the
        // order), differentiable on the JIT backends
        if constexpr (dr::is_jit_v<Float>)
            if (m_load.index.active())
                cb->put("data", m_sampler.index_values, ParamFlags::Differentiable);
        if (m_sampler.counting()) {
            std::vector<uint64_t> counts = m_sampler.counter_values();
            for (size_t i = 0; i < counts.size(); ++i) {
                m_trav.counters[i] = (double) counts[i];
                put(nanovdb_drjit::COUNTER_NAMES[i], m_trav.counters[i]);
            }
        }
    }

    std::string to_string() const override {
        std::ostringstream oss;
        oss << "NanoVDBVolume[" << std::endl
            << "  filename = \"" << m_filename << "\"," << std::endl
            << "  grid = \"" << m_grid_name << "\"," << std::endl
            << "  grid_type = " << nanovdb_loader::grid_type_name(m_load.facts.grid_type) << ","
            << std::endl
            << "  grid_class = " << nanovdb_loader::grid_class_name(m_load.facts.grid_class) << ","
            << std::endl;
        if (m_load.vdb.imported)
            oss << "  converted = from .vdb at load (" << m_load.vdb.convert_seconds << " s)"
                << (m_load.fogged ? ", a level set made a fog volume" : "") << "," << std::endl;
        oss
            << "  channels = " << m_channel_count << "," << std::endl
            << "  filter_type = " << FILTER_NAMES[(size_t) m_filter] << "," << std::endl
            << "  wrap_mode = " << (m_clamp ? "clamp" : "tree") << "," << std::endl
            << "  use_grid_transform = " << m_use_grid_transform << "," << std::endl
            << "  to_local = " << string::indent(m_to_local, 13) << "," << std::endl
            << "  bbox = " << string::indent(m_bbox) << "," << std::endl
            << "  index_min = " << m_index_min_host << "," << std::endl
            << "  dimensions = " << m_resolution_host << "," << std::endl
            << "  background = " << m_background_host << "," << std::endl
            << "  max = " << max() << "," << std::endl
            << "  grid_max = " << m_load.facts.grid_max << "," << std::endl
            << "  bytes = " << m_load.facts.grid_bytes + m_load.second_facts.grid_bytes << ","
            << std::endl
            << "  backend_bytes = " << backend_bytes() << "," << std::endl
            << "  majorant_bytes = " << m_load.facts.majorant_bytes << "," << std::endl
            << (m_load.facts.scale_bytes
                    ? "  spectral_scale_bytes = " + std::to_string(m_load.facts.scale_bytes) + ",\n"
                    : std::string())
            << "  local_majorant_ratio = " << m_load.facts.majorant_ratio << "," << std::endl;
        if (m_sampler.counting()) {
            std::vector<uint64_t> counts = m_sampler.counter_values();
            for (size_t i = 0; i < counts.size(); ++i)
                oss << "  " << nanovdb_drjit::COUNTER_NAMES[i] << " = " << counts[i] << ","
                    << std::endl;
        }
        oss << "  reader = " << (m_sampler.reader.root_indexed ? "root index" : "root search")
            << (m_sampler.reader.compact_offsets ? ", 32-bit child offsets"
                                                 : ", 64-bit child offsets")
            << std::endl
            << "]";
        return oss.str();
    }

    // =====================================================================
    //  Local majorants (nanovdb_mitsuba/local_majorants.h): the sampler's
    //  walk in "cell space" (voxel ijk covers [ijk, ijk + 1)^3, relative to
    //  a multiple of 4096 near the box)
    // =====================================================================

    // No MI_MASK_ARGUMENT here: on scalar variants it would make every call
    // active, and the walk is stepped with masks (a lane that met a null
    // collision stays in its segment).

    std::string source_name() const override {
        return "\"" + m_filename + "\" grid \"" + m_load.facts.name + "\"";
    }
    uint32_t grid_class_code() const override { return m_load.facts.grid_class; }

    ScalarFloat local_majorant_ratio() const override {
        node_majorants();
        if (m_load.index.active()) { // (the backend's rebuild: computed when asked)
            auto *self = const_cast<NanoVDBVolume *>(this);
            self->m_load.facts.majorant_ratio = self->m_load.index.majorant_ratio(m_sampler);
        }
        return m_channel_count == 6 ? 1.f : m_load.facts.majorant_ratio;
    }

    Float majorant_bound() const override {
        node_majorants();
        // (max(), as the lookups' clamp holds it: set with it, opaque, traversed)
        Float bound = dr::detach(m_sampler.max);
        if (m_second)
            bound = dr::maximum(bound, dr::detach(m_second->max));
        return bound;
    }

    bool stochastic_lookups() const override {
        return m_filter == Filter::StochasticTrilinear || m_filter == Filter::StochasticTricubic;
    }

    void set_lookup_offsets(const Vector3f *u) const override { s_offsets = { this, u }; }

    WalkRay walk_ray(const Ray3f &ray, const Float &thin_depth, Mask /* active */) const override {
        WalkRay r;
        for (int i = 0; i < 3; ++i) {
            r.origin[i] = m_cell_from_world(i, 3);
            r.direction[i] = 0.f;
            for (int j = 0; j < 3; ++j) {
                r.origin[i] = dr::fmadd(m_cell_from_world(i, j), ray.o[j], r.origin[i]);
                r.direction[i] = dr::fmadd(m_cell_from_world(i, j), ray.d[j], r.direction[i]);
            }
        }
        // A chord through a cell of D voxels is at most D sqrt(3) / |direction| long in t
        r.coarse_limit = thin_depth * dr::norm(r.direction) * 0.57735026918962576f;
        return r;
    }

    Walk walk_begin(const WalkRay &r, const Float &tmin, const Float &tmax, Mask active,
                    bool controls) const override {
        return m_sampler.walk_begin(Array3f(r.origin), Array3f(r.direction), tmin, tmax,
                                    r.coarse_limit, active, controls);
    }

    Mask walk_advance(Walk &walk, const WalkRay &r, Mask active, bool controls) const override {
        return m_sampler.walk_advance(walk, Array3f(r.origin), Array3f(r.direction),
                                      r.coarse_limit, active, controls);
    }

    // =====================================================================
    //  Its leaves, for an emission sampler (nanovdb_mitsuba/grid_units.h),
    //  in the walk's cell space: voxel a (absolute) is the cell [a - base,
    //  a - base + 1)
    // =====================================================================

    uint32_t unit_leaf_count() const override {
        return m_sampler.leaves_addressable() && !m_second ? m_leaf_count : 0;
    }

    Point3f leaf_voxel_point(const UInt32 &leaf, const UInt32 &n, Mask active) const override {
        Vector3f local(Float(n >> 6), Float((n >> 3) & 7u), Float(n & 7u));
        return world_from_cell(leaf_cell(leaf, active) + local + .5f);
    }

    Point3f leaf_block_point(const UInt32 &leaf, const UInt32 &block, const Point3f &u,
                             Mask active) const override {
        Vector3f b(Float(block >> 4), Float((block >> 2) & 3u), Float(block & 3u));
        return world_from_cell(leaf_cell(leaf, active) + 2.f * (b + Vector3f(u)));
    }

    uint32_t unit_tile_count() const override {
        return m_sampler.leaves_addressable() && !m_second ? m_tile_count : 0;
    }

    std::pair<Point3f, Float> tile_point(const UInt32 &tile, const Point3f &u,
                                         Mask active) const override {
        // (the table: the tiles' value words, then per tile origin x, y, z, log2dim)
        const UInt32 at = m_tile_count + 4u * tile;
        const UInt32 log2dim = read_tile_word(at + 3u, active);
        const Float dim = dr::reinterpret_array<Float>((log2dim + 127u) << 23); // (2^log2dim)
        Vector3f c;
        for (int k = 0; k < 3; ++k) // (cell space, as leaf_cell)
            c[k] = Float(dr::reinterpret_array<Int32>(
                read_tile_word(at + uint32_t(k), active) -
                dr::reinterpret_array<UInt32>(m_sampler.majorants.base[k])));
        return { world_from_cell(c + dim * Vector3f(u)), dim * dim * dim };
    }

    std::tuple<UInt32, UInt32, Mask> locate_unit(const Point3f &p, Mask active) const override {
        Vector3f c;
        for (int i = 0; i < 3; ++i) {
            c[i] = m_cell_from_world(i, 3);
            for (int j = 0; j < 3; ++j)
                c[i] = dr::fmadd(m_cell_from_world(i, j), p[j], c[i]);
        }
        using Coord = nanovdb_drjit::Coord<UInt32>;
        const auto cell = nanovdb_drjit::index_floor(Array3f(c));
        Coord ijk;
        for (int k = 0; k < 3; ++k) // (int32 wrap-around, as the index space)
            ijk[k] = dr::reinterpret_array<Int32>(dr::reinterpret_array<UInt32>(cell[k]) +
                                                  dr::reinterpret_array<UInt32>(m_sampler.majorants.base[k]));
        nanovdb_drjit::AddressAndLevel<UInt32> al = m_sampler.value_address_at(ijk, active);
        auto [unit, found] = m_sampler.leaf_of(al, active);
        UInt32 l[3];
        for (int k = 0; k < 3; ++k)
            l[k] = dr::reinterpret_array<UInt32>(ijk[k]) & 7u;
        UInt32 block = dr::select(found, ((l[0] >> 1) << 4) | ((l[1] >> 1) << 2) | (l[2] >> 1),
                                  0u);
        if (m_tile_count > 0) {
            // A tile: its value word among the sorted ones
            const Mask tile = active && al.level != nanovdb_drjit::LEVEL_LEAF &&
                              al.level != nanovdb_drjit::LEVEL_BACKGROUND;
            const UInt32 t = nanovdb_drjit::last_at_most<UInt32>(
                m_tile_count,
                [&](const UInt32 &i, const Mask &ok) { return read_tile_word(i, ok); },
                al.address, tile);
            const Mask hit = tile && read_tile_word(t, tile) == al.address;
            dr::masked(unit, hit) = m_leaf_count + t;
            found |= hit;
        }
        return { unit, block, found };
    }

    ScalarFloat voxel_volume() const override { return m_voxel_volume; }

    MI_DECLARE_CLASS(NanoVDBVolume)

private:
    /// The active tiles' table (tile_point, locate_unit), on the backend
    void set_tiles(std::vector<nanovdb_loader::ActiveTile> tiles) {
        m_tile_count = uint32_t(tiles.size());
        std::vector<uint32_t> t(5 * tiles.size());
        for (size_t i = 0; i < tiles.size(); ++i) {
            t[i] = tiles[i].value_word;
            for (int k = 0; k < 3; ++k)
                t[tiles.size() + 4 * i + k] = uint32_t(tiles[i].origin[k]);
            t[tiles.size() + 4 * i + 3] = tiles[i].log2dim;
        }
        if constexpr (dr::is_jit_v<Float>)
            m_tile_table = t.empty() ? UInt32() : dr::load<UInt32>(t.data(), t.size());
        else
            m_tile_table = std::move(t);
    }

    UInt32 read_tile_word(const UInt32 &i, const Mask &active) const {
        if constexpr (dr::is_jit_v<Float>)
            return dr::gather<UInt32>(m_tile_table, i, active);
        else
            return active ? m_tile_table[i] : 0u;
    }

    /// Leaf `leaf`'s origin in cell space
    Vector3f leaf_cell(const UInt32 &leaf, Mask active) const {
        const auto o = m_sampler.leaf_origin(leaf, active);
        Vector3f c;
        for (int k = 0; k < 3; ++k) // (int32 wrap-around, as the index space)
            c[k] = Float(dr::reinterpret_array<Int32>(
                dr::reinterpret_array<UInt32>(o[k]) -
                dr::reinterpret_array<UInt32>(m_sampler.majorants.base[k])));
        return c;
    }

    Point3f world_from_cell(const Vector3f &c) const {
        Point3f p;
        for (int i = 0; i < 3; ++i) {
            p[i] = m_world_from_cell(i, 3);
            for (int j = 0; j < 3; ++j)
                p[i] = dr::fmadd(m_world_from_cell(i, j), c[j], p[i]);
        }
        return p;
    }

    static constexpr uint32_t kVec3f = nanovdb_drjit::layout::GRID_TYPE_VEC3F;

    std::string channels_str() const {
        return m_channel_count == 1 ? "a single channel"
                                    : std::to_string(m_channel_count) + " channels";
    }

    // =====================================================================
    //  Positions: local (or, with use_grid_transform, world) -> index space.
    //  The index position is computed relative to the box minimum in
    //  floating point and the integer minimum added last (by the sampler),
    //  so grids far from the origin keep full precision.
    // =====================================================================

    /// The voxel a nearest lookup reads (relative to the box minimum), or
    /// the index position a trilinear one interpolates at
    struct IndexPosition {
        Vector3i voxel;
        Vector3f rel;
    };

    IndexPosition index_position(const Interaction3f &it) const {
        IndexPosition out;
        if (!m_use_grid_transform) {
            Point3f p = m_to_local * it.p;
            // Same arithmetic as Dr.Jit's texture (gridvolume), so both plugins
            // pick the same voxels and weights
            if (m_filter == Filter::Nearest)
                out.voxel = nanovdb_drjit::index_floor(Array3f(p * m_resolution));
            else
                out.rel = dr::fmadd(p, m_resolution, -.5f);
        } else {
            Point4f p = m_index_from_world * Point4f(it.p.x(), it.p.y(), it.p.z(), 1.f);
            out.rel = Vector3f(p.x(), p.y(), p.z());
            if (m_filter == Filter::Nearest)
                out.voxel = nanovdb_drjit::index_floor(Array3f(out.rel + .5f));
        }
        if (stochastic_lookups())
            out.voxel = m_sampler.stochastic_voxel(Array3f(out.rel), Array3f(offsets(out.rel)),
                                                   m_filter == Filter::StochasticTricubic);
        return out;
    }

    /// A stochastic filter's offsets at `rel`: the integrator's (from its
    /// sampler, set_lookup_offsets) or a hash of the position
    Vector3f offsets(const Vector3f &rel) const {
        if (s_offsets.owner == this && s_offsets.u)
            return *s_offsets.u;
        return Vector3f(nanovdb_drjit::hash_offsets(Array3f(rel), m_seed));
    }

    /// Whether `voxel` is what a lookup reads (nearest and stochastic filters)
    bool one_voxel() const { return m_filter != Filter::Trilinear; }

    /// Value at the local point of `it` (scalar grids). Inside the volume's
    /// box every value is at most max(); points outside it (use_grid_transform
    /// with a rotation, a shape larger than the volume) may reach other
    /// values of the tree, which the sampler clamps to max(), so that max()
    /// bounds every lookup, as a majorant must.
    Float lookup(const Interaction3f &it, Mask active) const {
        MI_MASK_ARGUMENT(active);
        IndexPosition pos = index_position(it);
        return one_voxel() ? m_sampler.nearest(pos.voxel, active)
                           : m_sampler.trilinear(Array3f(pos.rel), active);
    }

    /// The 3-vector at the local point of `it` (a Vec3f grid)
    Vector3f lookup3(const Sampler &s, const Interaction3f &it, Mask active) const {
        MI_MASK_ARGUMENT(active);
        IndexPosition pos = index_position(it);
        return Vector3f(one_voxel() ? s.nearest3(pos.voxel, active)
                                    : s.trilinear3(Array3f(pos.rel), active));
    }

    /// eval() of a Vec3f grid in spectral variants, as gridvolume's
    /// interpolate_spectral: the sRGB-model spectrum of each voxel's
    /// coefficients, interpolated, times the interpolated scale
    UnpolarizedSpectrum lookup_spectral(const Interaction3f &it, Mask active) const {
        namespace ndr = nanovdb_drjit;
        m_sampler.count(ndr::Counter::Lookup, active);
        IndexPosition pos = index_position(it);
        auto corner_value = [&](const UInt32 &address, const UInt32 &level,
                                const ndr::Coord<UInt32> &c) {
            Vector3f coeff(m_sampler.read3(address, active));
            return std::make_pair(srgb_model_eval<UnpolarizedSpectrum>(coeff, it.wavelengths),
                                  m_sampler.value_scale(address, level, c, active));
        };
        if (one_voxel()) {
            ndr::AddressAndLevel<UInt32> al = m_sampler.address3(pos.voxel, active);
            auto [spectrum, scale] = corner_value(al.address, al.level,
                                                  m_sampler.absolute(pos.voxel));
            return spectrum * scale;
        }
        typename Sampler::Stencil s = m_sampler.stencil3(Array3f(pos.rel), active);
        UnpolarizedSpectrum spectrum(0.f);
        Float scale = 0.f;
        for (uint32_t corner = 0; corner < 8; ++corner) {
            ndr::Coord<UInt32> c = ndr::coord_add<UInt32>(s.ijk0, corner & 1u,
                                                          (corner >> 1) & 1u, (corner >> 2) & 1u);
            auto [sp, sc] = corner_value(s.corners.address[corner], s.corners.level[corner], c);
            spectrum = dr::fmadd(sp, s.weight[corner], spectrum);
            scale = dr::fmadd(sc, s.weight[corner], scale);
        }
        // (m_sampler.max: max(), as a variable the kernels share and a frozen
        // function reads among its inputs; the host number was a literal)
        return spectrum * dr::minimum(scale, m_sampler.max);
    }

    /// The backend's bytes of the grid(s) and what lives beside them
    size_t backend_bytes() const {
        return m_load.facts.backend_bytes + m_load.second_facts.backend_bytes;
    }

    /// The per-node majorants of an index grid whose values changed, again
    /// (index_updates.h; the walk's: volpathlocal asks for
    /// local_majorant_ratio() and majorant_bound() before every render).
    /// Logically const: the bounds of the values the volume holds.
    void node_majorants() const {
        if (!m_load.index.stale)
            return;
        m_load.index.refuse_while_recording(m_filename);
        auto *self = const_cast<NanoVDBVolume *>(this);
        nvdb::IndexBounds b =
            self->m_load.index.rebound(self->m_sampler, m_clamp, m_filename, m_grid_name);
        self->m_load.facts.max = b.max;
        for (int k = 0; k < 3; ++k)
            self->m_load.facts.max3[k] = b.max3[k];
        self->m_load.facts.grid_max = b.grid_max;
        self->m_load.facts.majorant_ratio = b.majorant_ratio;
    }

public:
    void parameters_changed(const std::vector<std::string> &keys = {}) override {
        if (m_load.index.active() &&
            (keys.empty() || std::find(keys.begin(), keys.end(), "data") != keys.end())) {
            // the value policy and max() on the backend (index_updates.h)
            nvdb::IndexBounds b = m_load.index.values_changed(m_sampler, m_filename);
            m_load.facts.max = b.max;
            for (int k = 0; k < 3; ++k)
                m_load.facts.max3[k] = b.max3[k];
        }
        Base::parameters_changed(keys);
    }

private:

    /// The active index box [min, max] (inclusive), or a dense source's
    /// whole box, becomes the volume's extent. An empty grid reads as the
    /// single voxel at the origin, i.e. its background everywhere.
    void set_index_box(const nanovdb_loader::GridSummary &summary,
                       const std::optional<nanovdb_loader::IndexBox> &box) {
        m_background_host = summary.background;
        ScalarVector3i bmin(summary.bbox_min[0], summary.bbox_min[1], summary.bbox_min[2]),
                       bmax(summary.bbox_max[0], summary.bbox_max[1], summary.bbox_max[2]);
        if (summary.empty)
            bmin = bmax = ScalarVector3i(0);
        if (box) {
            bmin = ScalarVector3i(box->lo[0], box->lo[1], box->lo[2]);
            bmax = ScalarVector3i(box->hi[0], box->hi[1], box->hi[2]);
        }
        m_index_min_host = bmin;
        // Extent as 64-bit arithmetic: max - min + 1 overflows int32 for boxes
        // spanning more than 2^31 voxels.
        for (int k = 0; k < 3; ++k) {
            int64_t extent = int64_t(bmax[k]) - int64_t(bmin[k]) + 1;
            if (extent > std::numeric_limits<int32_t>::max())
                Throw("nanovdbvolume: \"%s\": grid \"%s\" spans %lld voxels along "
                      "axis %d, more than a Mitsuba volume resolution can hold.",
                      m_filename, m_grid_name, (long long) extent, k);
            m_resolution_host[k] = (int32_t) extent;
            m_index_min_box[k] = bmin[k];
            m_resolution_box[k] = (int32_t) extent;
        }
        m_sampler.set_box(m_index_min_box, m_resolution_box, m_load.facts.grid_type, m_clamp);
        // Per-file values reach kernels as opaque variables, so that loading
        // another file does not recompile them.
        for (int k = 0; k < 3; ++k)
            m_resolution[k] = dr::opaque<Float>((ScalarFloat) m_resolution_host[k]);
    }

    /// use_grid_bbox (gridvolume's): the unit cube maps to the box the
    /// volume's values occupy in world space: a VolumeGrid's bbox, or for a
    /// file the world bounds of its box's voxels (the cells [m - 1/2, M +
    /// 1/2] of index space through the grid's map: the placement of
    /// use_grid_transform when the map has no rotation, its bounding box
    /// when it has one)
    void place_by_grid_bbox(const nanovdb_loader::GridSummary &summary,
                            const std::optional<ScalarAffineTransform4f> &grid_bbox_to_unit) {
        if (grid_bbox_to_unit) { // a VolumeGrid: as gridvolume does
            m_to_local = *grid_bbox_to_unit * m_to_local;
            update_bbox();
            return;
        }
        ScalarBoundingBox3f bb;
        for (int corner = 0; corner < 8; ++corner)
            bb.expand(box_corner_in_grid_world(summary, corner));
        if (!bb.valid() || dr::any(bb.extents() <= 0.f))
            Throw("nanovdbvolume: \"%s\": use_grid_bbox: the grid's box %s has no volume",
                  m_filename, bb);
        ScalarAffineTransform4f bbox_to_unit = ScalarAffineTransform4f::scale(dr::rcp(bb.extents())) *
                                               ScalarAffineTransform4f::translate(-bb.min);
        m_to_local = bbox_to_unit * m_to_local;
        update_bbox();
    }

    /// With use_grid_transform: local space = the grid's world space.
    void set_grid_transform(const nanovdb_loader::GridSummary &summary) {
        // rel = inv_mat * (world - vec) - min, composed with to_local in
        // double precision and rounded once (placement.h)
        nanovdb_placement::Matrix4d m =
            nanovdb_placement::rel_from_grid_world(summary, index_min()) * to_local_d();
        m_index_from_world_host = m;
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_index_from_world(r, c) = dr::opaque<Float>((ScalarFloat) m(r, c));

        // World-space bounds: the voxels' cells [min - 0.5, max + 0.5] of the
        // index box, mapped by the grid transform and then by to_world.
        ScalarAffineTransform4f to_world = m_to_local.inverse();
        m_bbox = ScalarBoundingBox3f();
        for (int corner = 0; corner < 8; ++corner)
            m_bbox.expand(to_world * box_corner_in_grid_world(summary, corner));
    }

    /// Corner `corner` (bit k: the high side of axis k) of the cells of the
    /// volume's index box through the grid's map (placement.h), rounded once
    ScalarPoint3f box_corner_in_grid_world(const nanovdb_loader::GridSummary &summary,
                                           int corner) const {
        nanovdb_placement::Double3 w = nanovdb_placement::box_corner_in_grid_world(
            summary, index_min(), box_resolution(), corner);
        return ScalarPoint3f((float) w[0], (float) w[1], (float) w[2]);
    }

    /// World -> cell space of the majorant walk (placement.h), rounded once
    void set_cell_transform() {
        nanovdb_placement::Int3 base = { m_load.cell_base[0], m_load.cell_base[1],
                                         m_load.cell_base[2] };
        nanovdb_placement::Matrix4d m = m_use_grid_transform
            ? nanovdb_placement::cell_from_rel_world(m_index_from_world_host, index_min(), base)
            : nanovdb_placement::cell_from_world_unit_cube(
                  to_local_d(), index_min(), box_resolution(), base);
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_cell_from_world(r, c) = dr::opaque<Float>((ScalarFloat) m(r, c));
        // ... and back (emission sampling: GridUnits), with one voxel's volume
        const nanovdb_placement::Matrix4d w = dr::inverse(m);
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_world_from_cell(r, c) = dr::opaque<Float>((ScalarFloat) w(r, c));
        m_voxel_volume = (ScalarFloat) std::abs(
            w(0, 0) * (w(1, 1) * w(2, 2) - w(1, 2) * w(2, 1)) -
            w(0, 1) * (w(1, 0) * w(2, 2) - w(1, 2) * w(2, 0)) +
            w(0, 2) * (w(1, 0) * w(2, 1) - w(1, 1) * w(2, 0)));
    }

    nanovdb_placement::Int3 index_min() const {
        return { m_index_min_host[0], m_index_min_host[1], m_index_min_host[2] };
    }
    nanovdb_placement::Int3 box_resolution() const {
        return { m_resolution_host[0], m_resolution_host[1], m_resolution_host[2] };
    }
    /// to_local (world -> local), in double
    nanovdb_placement::Matrix4d to_local_d() const {
        nanovdb_placement::Matrix4d m;
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m(r, c) = (double) m_to_local.matrix(r, c);
        return m;
    }

private:
    // Backend (JIT variables, opaque per file; plain values on scalars)
    Sampler m_sampler;                 // the grid and its lookups (channels 0-2 of 6)
    std::unique_ptr<Sampler> m_second; // 6 channels: channels 3-5
    Vector3f m_resolution;             // the box's extent in voxels, as Float
    Matrix4f m_index_from_world;       // use_grid_transform: world -> index - min
    Matrix4f m_cell_from_world;        // world -> the walk's cell space
    Matrix4f m_world_from_cell;        // ... and back (GridUnits)

    // Host
    /// The load's settings, and what it learnt: the grids' facts, a .vdb's
    /// import, an index grid's update state (grid_load.h)
    nvdb::GridLoad<Float, Spectrum> m_load;
    ScalarVector3i m_index_min_host;
    ScalarVector3i m_resolution_host;
    int32_t m_index_min_box[3] = {}, m_resolution_box[3] = {};
    ScalarFloat m_background_host = 0.f;
    uint32_t m_leaf_count = 0;         // the grid's leaves (GridUnits)
    uint32_t m_tile_count = 0;         // its active tiles (GridUnits), and their table:
    /// sorted value words, then per tile origin x, y, z, log2dim (tile_point)
    std::conditional_t<dr::is_jit_v<Float>, UInt32, std::vector<uint32_t>> m_tile_table;
    ScalarFloat m_voxel_volume = 0.f;  // one voxel's world volume (GridUnits)
    dr::Matrix<double, 4> m_index_from_world_host; // use_grid_transform, in double
    Filter m_filter = Filter::Trilinear;
    uint32_t m_seed = 0;               // stochastic filters' hash seed (eval())
    bool m_clamp = false;              // wrap_mode "clamp": positions clamped to the box
    bool m_use_grid_transform = false;
    std::string m_filename, m_grid_name;
    /// traverse()'s copies of what it exposes
    struct {
        uint32_t grid_type = 0, grid_class = 0, channels = 1;
        ScalarPoint3f bbox_min, bbox_max;
        ScalarFloat max = 0.f;
        bool rebuild_on_backend = false;
        uint32_t rebuild_replays = 0;
        double grid_bytes = 0, backend_bytes = 0, majorant_bytes = 0, scale_bytes = 0,
               value_bytes = 0;
        double counters[(uint32_t) nanovdb_drjit::Counter::Count] = {};
    } m_trav;

    /// The offsets the integrator gave this thread's lookups (set_lookup_offsets)
    struct Offsets {
        const NanoVDBVolume *owner;
        const Vector3f *u;
    };
    static inline thread_local Offsets s_offsets = { nullptr, nullptr };

    // Dr.Jit's traversal of the volume's variables: dr.freeze reads them as
    // a frozen function's inputs, each time before it records or replays.
    // The per-node majorants of updated values are rebuilt first, so that
    // the function reads the current table and bounds (a replay runs no C++
    // of ours: the walk's own request comes only while it records)
    NVDB_MI_TRAVERSE_CB_REFRESHED(Base, node_majorants(), m_sampler, m_second, m_resolution,
                                  m_index_from_world, m_cell_from_world, m_world_from_cell,
                                  m_tile_table)
};

MI_EXPORT_PLUGIN(NanoVDBVolume)
NAMESPACE_END(mitsuba)
