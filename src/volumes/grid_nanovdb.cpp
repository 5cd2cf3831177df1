#include <mitsuba/core/fresolver.h>
#include <mitsuba/core/properties.h>
#include <mitsuba/core/string.h>
#include <mitsuba/core/transform.h>
#include <mitsuba/render/srgb.h>
#include <mitsuba/render/volume.h>

#include <nanovdb_drjit/backend_buffer.h>
#include <nanovdb_drjit/fast_readers.h>
#include <nanovdb_drjit/majorant_walk.h>
#include <nanovdb_drjit/stencil.h>
#include <nanovdb_loader/load.h>
#include <nanovdb_loader/majorants.h>
#include <nanovdb_mitsuba/local_majorants.h>
#include <nanovdb_mitsuba/plugin_variants.h>

#include "memory_source.h"

#include <array>
#include <atomic>
#include <optional>
#include <tuple>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <vector>

NAMESPACE_BEGIN(mitsuba)

/**!

.. _volume-nanovdbvolume:

NanoVDB sparse volume (:monosp:`nanovdbvolume`)
-----------------------------------------------

.. pluginparameters::

 * - filename
   - |string|
   - Path of the NanoVDB file (``.nvdb``) to load. Files written by NanoVDB
     32.3 to 32.9 (OpenVDB 10 to 13) are read, uncompressed or with the ZIP
     or BLOSC codec, including files with several grids or segments and raw
     grid buffers.

 * - grid
   - |string|
   - Which grid of the file to use: its name, or its index in the file
     (``"0"``, ``"1"``, ...) when no grid has that name. Only that grid's
     bytes are read. Types: float, Half, Fp4, Fp8, Fp16, FpN (one channel)
     and Vec3f (three). (Default: the first grid of one of these types)

 * - filter_type
   - |string|
   - ``trilinear``: interpolate between voxel centres, as NanoVDB's own
     trilinear sampler does; ``nearest``: the value of the voxel that
     contains the point. (Default: ``trilinear``)

 * - use_grid_transform
   - |bool|
   - If ``false``, the volume's local unit cube :math:`[0, 1]^3` spans the
     grid's active voxels exactly as ``gridvolume`` spans a dense array of the
     same box, so the two plugins render the same image under the same
     ``to_world``. If ``true``, local space is the grid's own world space
     (its index-to-world map from the file), so the volume lines up with
     other VDB tools. (Default: ``false``)

 * - raw
   - |bool|
   - Vec3f grids in spectral variants: ``false`` turns the colours into
     spectra (``eval()``); ``true`` keeps the raw vectors (``eval_3()``), as
     ``gridvolume``'s ``raw``. (Default: ``false``)

 * - invalid_values
   - |string|
   - What to do with NaN, infinite and negative voxel or tile values:
     ``error``: refuse a grid with NaN or infinite values, naming the first
     offending voxel (negative values load, with a warning);
     ``clamp``: replace NaN by 0, +Inf by the largest finite value of the
     grid, -Inf and negative values by 0, with a warning that counts them.
     (Default: ``error``)

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
Dr.Jit translation of PNanoVDB. Values outside the active voxels are whatever
the tree stores there -- normally the grid's background value (VDB
semantics). Consequently, ``trilinear`` interpolation in the outer half voxel
of the active box blends towards the background, where ``gridvolume`` clamps
to the edge voxel.

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
the luminance, ``max_per_channel()`` each channel's ``max()``. Other grid
types (double, int, index, points, masks) fail with a message that names the
type and lists the supported ones.

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

template <typename Float, typename Spectrum>
class NanoVDBVolume final : public Volume<Float, Spectrum>,
                            public LocalMajorants<Float, Spectrum> {
public:
    MI_IMPORT_BASE(Volume, update_bbox, m_to_local, m_bbox, m_channel_count)
    MI_IMPORT_TYPES()
    using Walk = typename LocalMajorants<Float, Spectrum>::Walk;
    using WalkRay = typename LocalMajorants<Float, Spectrum>::WalkRay;
    using Array3f = dr::Array<Float, 3>;

    /// The grid's 32-bit words on the backend: a JIT array (LLVM: mapped host
    /// memory; CUDA: device memory), or a plain host allocation on scalars
    using GridBuffer = std::conditional_t<dr::is_jit_v<Float>, UInt32,
                                          std::unique_ptr<uint32_t[], void (*)(void *)>>;
    using Reader = nanovdb_drjit::Reader<UInt32>;
    /// Per-value scales of a spectral Vec3f grid: a JIT array or a host vector
    using ScalarGridScales = std::conditional_t<dr::is_jit_v<Float>, Float, std::vector<float>>;

    NanoVDBVolume(const Properties &props) : Base(props), m_grid(empty_grid_buffer()) {
        // Where the values come from: a file, or values in memory (built
        // into a grid here: nanovdb_loader/build.h)
        const bool grid_object = props.has_property("grid") &&
                                 props.type("grid") == Properties::Type::Object;
        const int sources = int(props.has_property("filename")) + int(grid_object) +
                            int(props.has_property("data")) +
                            int(props.has_property("values") || props.has_property("coords"));
        if (sources != 1)
            Throw("nanovdbvolume: give exactly one of \"filename\" (a .nvdb file), \"grid\" "
                  "(a VolumeGrid), \"data\" (a dense tensor) or \"values\" with \"coords\" "
                  "(voxels one by one); %d were given", sources);
        std::optional<MemorySource<Float, Spectrum>> memory;
        if (props.has_property("filename")) {
            m_filename = file_resolver()->resolve(props.get<std::string_view>("filename")).string();
        } else {
            memory.emplace(props, grid_object);
            m_filename = memory->label;
        }

        std::string_view filter = props.get<std::string_view>("filter_type", "trilinear");
        if (filter == "nearest")
            m_nearest = true;
        else if (filter != "trilinear")
            Throw("nanovdbvolume: \"%s\": invalid filter_type \"%s\", must be one of: "
                  "\"nearest\" or \"trilinear\"", m_filename, filter);

        std::string_view invalid = props.get<std::string_view>("invalid_values", "error");
        if (invalid == "clamp")
            m_invalid_values = nanovdb_loader::InvalidValues::Clamp;
        else if (invalid != "error")
            Throw("nanovdbvolume: \"%s\": invalid value \"%s\" for invalid_values, must be "
                  "one of: \"error\" or \"clamp\"", m_filename, invalid);

        // Outside the box: the tree's own values (VDB semantics; the default
        // for files and voxel lists) or the edge voxels (gridvolume's
        // convention, and its default: the default for dense data)
        const bool dense_source = grid_object || props.has_property("data");
        std::string_view wrap = props.get<std::string_view>("wrap_mode",
                                                             dense_source ? "clamp" : "tree");
        if (wrap == "clamp")
            m_clamp = true;
        else if (wrap == "repeat" || wrap == "mirror")
            Throw("nanovdbvolume: \"%s\": wrap_mode \"%s\" is not supported: a sparse grid has "
                  "no period to repeat or mirror; use \"clamp\" (the edge voxels, gridvolume's "
                  "default) or \"tree\" (the tree's own values)", m_filename, wrap);
        else if (wrap != "tree")
            Throw("nanovdbvolume: \"%s\": invalid wrap_mode \"%s\", must be one of: \"tree\" "
                  "or \"clamp\"", m_filename, wrap);

        m_use_grid_transform = props.get<bool>("use_grid_transform", false);
        const bool use_grid_bbox = props.get<bool>("use_grid_bbox", false);
        if (use_grid_bbox && m_use_grid_transform)
            Throw("nanovdbvolume: \"%s\": use_grid_bbox and use_grid_transform both place the "
                  "volume by the grid's own coordinates; set one of them", m_filename);
        if (use_grid_bbox && (props.has_property("data") || props.has_property("values")))
            Throw("nanovdbvolume: \"%s\": use_grid_bbox needs a bounding box, which a file or a "
                  "VolumeGrid has and a tensor does not (as for gridvolume)", m_filename);
        // gridvolume's hardware textures (CUDA): nothing to switch here, the
        // tree is traversed on every backend
        if (props.has_property("accel"))
            Log(Debug, "nanovdbvolume: \"%s\": accel=%s has no effect (no texture units: the "
                       "tree is traversed)", m_filename, props.get<bool>("accel"));
        m_raw = props.get<bool>("raw", false);
        m_count = props.get<bool>("count_lookups", false);
        if constexpr (dr::is_jit_v<Float>) {
            if (m_count) {
                m_counters = dr::zeros<UInt64>(kCounters);
                dr::make_opaque(m_counters);
            }
        }

        nanovdb_loader::GridSummary summary;
        std::optional<nanovdb_loader::IndexBox> box; // the volume's box, if not the active one
        if (props.has_property("filename")) {
            summary = load_grid(std::string(grid_object ? "" : props.get<std::string_view>("grid", "")));
        } else {
            nanovdb_loader::BuildOptions options;
            options.background = props.get<ScalarFloat>("background", 0.f);
            options.threshold = props.get<ScalarFloat>("threshold", 0.f);
            if (!std::isfinite(options.background))
                Throw("nanovdbvolume: \"%s\": background must be finite, got %f", m_filename,
                      options.background);
            if (!(options.threshold >= 0.f))
                Throw("nanovdbvolume: \"%s\": threshold must be >= 0, got %f", m_filename,
                      options.threshold);
            auto [built, dense_box] = memory->build(options);
            box = dense_box;
            if (built.left_out)
                Log(Info, "nanovdbvolume: \"%s\": %llu voxels within threshold = %f of the "
                          "background left out", m_filename, (unsigned long long) built.left_out,
                    options.threshold);
            summary = load_bytes(options.name, built.bytes, box);
        }
        set_index_box(summary, box);
        if (use_grid_bbox)
            place_by_grid_bbox(summary, memory ? memory->bbox_transform : std::nullopt);
        if (m_use_grid_transform)
            set_grid_transform(summary);
        set_cell_transform(summary);
        m_channel_count = m_grid_type == nanovdb_drjit::layout::GRID_TYPE_VEC3F ? 3 : 1;

        // gridvolume's max_value: a bound given by the user. A larger one
        // than the values' own is kept (a looser majorant: slower, still
        // unbiased); a smaller one would bias every render, so it is refused
        // with a warning, and the values' own is kept.
        if (props.has_property("max_value")) {
            ScalarFloat given = props.get<ScalarFloat>("max_value");
            if (given >= m_max_host) {
                m_max_host = given;
                m_max = dr::opaque<Float>(m_max_host);
                m_max3_host = dr::maximum(m_max3_host, ScalarVector3f(given));
                for (int k = 0; k < 3; ++k)
                    m_max3[k] = dr::opaque<Float>(m_max3_host[k]);
            } else {
                Log(Warn, "nanovdbvolume: \"%s\": max_value = %f is below the largest value "
                          "lookups return (%f): a majorant that small would bias renders, "
                          "so max() stays %f", m_filename, given, m_max_host, m_max_host);
            }
        }
        Log(Debug, "Loaded \"%s\" grid \"%s\": index box [%s, %s + %s), %zu bytes, max %f",
            m_filename, m_grid_name, m_index_min_host, m_index_min_host, m_resolution_host,
            m_grid_bytes, m_max_host);
    }

    // =====================================================================
    //  Volume interface
    // =====================================================================

    // Vec3f grids behave like a 3-channel gridvolume: eval() is the colour
    // (RGB), its luminance (monochrome) or its sRGB-model spectrum
    // (spectral; raw=true refuses, as gridvolume does); eval_1() the
    // luminance; eval_3() the raw vector (not in spectral variants unless raw).

    UnpolarizedSpectrum eval(const Interaction3f &it, Mask active) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 3 && is_spectral_v<Spectrum> && m_raw)
            Throw("eval(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for a "
                  "spectrum, but its conversion into spectra was disabled (raw=true)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<UnpolarizedSpectrum>();
        if (m_channel_count == 1)
            return UnpolarizedSpectrum(lookup(it, active));
        if constexpr (is_monochromatic_v<Spectrum>)
            return UnpolarizedSpectrum(luminance(Color3f(lookup3(it, active))));
        else if constexpr (is_spectral_v<Spectrum>)
            return lookup_spectral(it, active);
        else
            return UnpolarizedSpectrum(lookup3(it, active));
    }

    Float eval_1(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 3 && is_spectral_v<Spectrum> && !m_raw)
            Throw("eval_1(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for "
                  "a scalar value, but its conversion into spectra was requested (raw=false)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<Float>();
        if (m_channel_count == 3)
            return luminance(Color3f(lookup3(it, active)));
        return lookup(it, active);
    }

    void eval_n(const Interaction3f &it, Float *out, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count == 3) {
            Vector3f v = lookup3(it, active);
            for (int k = 0; k < 3; ++k)
                out[k] = v[k];
            return;
        }
        out[0] = lookup(it, active);
    }

    Vector3f eval_3(const Interaction3f &it, Mask active = true) const override {
        MI_MASKED_FUNCTION(ProfilerPhase::TextureEvaluate, active);
        if (m_channel_count != 3)
            Throw("eval_3(): the nanovdbvolume \"%s\" (grid \"%s\") holds a single "
                  "channel, not a 3D vector", m_filename, m_grid_name);
        if (is_spectral_v<Spectrum> && !m_raw)
            Throw("eval_3(): the nanovdbvolume \"%s\" (grid \"%s\", Vec3f) was queried for "
                  "a 3D vector, but its conversion into spectra was requested (raw=false)",
                  m_filename, m_grid_name);
        if (dr::none_or<false>(active))
            return dr::zeros<Vector3f>();
        return lookup3(it, active);
    }

    dr::Array<Float, 6> eval_6(const Interaction3f &, Mask = true) const override {
        Throw("eval_6(): the nanovdbvolume \"%s\" (grid \"%s\") holds a single "
              "channel, not 6", m_filename, m_grid_name);
    }

    ScalarFloat max() const override { return m_max_host; }

    void max_per_channel(ScalarFloat *out) const override {
        if (m_channel_count == 3) {
            for (int k = 0; k < 3; ++k)
                out[k] = m_max3_host[k];
            return;
        }
        out[0] = m_max_host;
    }

    ScalarVector3i resolution() const override { return m_resolution_host; }

    std::string to_string() const override {
        std::ostringstream oss;
        oss << "NanoVDBVolume[" << std::endl
            << "  filename = \"" << m_filename << "\"," << std::endl
            << "  grid = \"" << m_grid_name << "\"," << std::endl
            << "  grid_type = " << nanovdb_loader::grid_type_name(m_grid_type) << "," << std::endl
            << "  grid_class = " << nanovdb_loader::grid_class_name(m_grid_class) << "," << std::endl
            << "  filter_type = " << (m_nearest ? "nearest" : "trilinear") << "," << std::endl
            << "  use_grid_transform = " << m_use_grid_transform << "," << std::endl
            << "  to_local = " << string::indent(m_to_local, 13) << "," << std::endl
            << "  bbox = " << string::indent(m_bbox) << "," << std::endl
            << "  index_min = " << m_index_min_host << "," << std::endl
            << "  dimensions = " << m_resolution_host << "," << std::endl
            << "  background = " << m_background_host << "," << std::endl
            << "  max = " << m_max_host << "," << std::endl
            << "  grid_max = " << m_grid_max_host << "," << std::endl
            << "  bytes = " << m_grid_bytes << "," << std::endl
            << "  backend_bytes = " << m_backend_bytes << "," << std::endl
            << "  majorant_bytes = " << m_majorant_bytes << "," << std::endl
            << (m_scale_bytes ? "  spectral_scale_bytes = " + std::to_string(m_scale_bytes) + ",\n"
                              : std::string())
            << "  local_majorant_ratio = " << m_majorant_ratio << "," << std::endl
            << counters_string()
            << "  reader = " << (m_reader.root_indexed ? "root index" : "root search")
            << (m_reader.compact_offsets ? ", 32-bit child offsets" : ", 64-bit child offsets")
            << std::endl
            << "]";
        return oss.str();
    }

    // =====================================================================
    //  Local majorants (nanovdb_mitsuba/local_majorants.h): the walk of
    //  nanovdb_drjit/majorant_walk.h in "cell space" (voxel ijk covers
    //  [ijk, ijk + 1)^3, relative to a multiple of 4096 near the box)
    // =====================================================================

    // No MI_MASK_ARGUMENT here: on scalar variants it would make every call
    // active, and the walk is stepped with masks (a lane that met a null
    // collision stays in its segment).

    ScalarFloat local_majorant_ratio() const override { return m_majorant_ratio; }

    ScalarFloat majorant_bound() const override { return m_max_host; }

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

    Walk walk_begin(const WalkRay &r, const Float &tmin, const Float &tmax,
                    Mask active) const override {
        Walk walk = with_walk_type([&](auto type) {
            return m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                return nanovdb_drjit::walk_begin<decltype(type)::value>(
                    buf, root, m_majorants, Array3f(r.origin), Array3f(r.direction), tmin,
                    tmax, r.coarse_limit, active);
            });
        });
        count(7, active);
        count_step(walk, active && nanovdb_drjit::walk_valid(walk));
        return walk;
    }

    Mask walk_advance(Walk &walk, const WalkRay &r, Mask active) const override {
        Mask more = with_walk_type([&](auto type) {
            return m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                return nanovdb_drjit::walk_advance<decltype(type)::value>(
                    buf, root, m_majorants, walk, Array3f(r.origin), Array3f(r.direction),
                    r.coarse_limit, active);
            });
        });
        count_step(walk, more);
        return more;
    }

    MI_DECLARE_CLASS(NanoVDBVolume)

private:
    // =====================================================================
    //  Lookups, by space. Local: the unit cube over the active box (default)
    //  or the grid's world space (use_grid_transform). Index: NanoVDB's
    //  integer voxel coordinates, values at integer positions. Kernels
    //  compute the index position *relative to the box minimum* in floating
    //  point and add the integer minimum last, so grids far from the origin
    //  keep full precision.
    // =====================================================================

    /// Value at the local point of `it`: local -> index, then the filter.
    /// Inside the volume's box every value is at most max(); points outside
    /// it (use_grid_transform with a rotation, a shape larger than the
    /// volume) may reach other values of the tree, which are clamped to
    /// max(), so that max() bounds every lookup, as a majorant must.
    Float lookup(const Interaction3f &it, Mask active) const {
        MI_MASK_ARGUMENT(active);
        count(0, active);
        Vector3f rel; // index position relative to m_index_min
        if (!m_use_grid_transform) {
            Point3f p = m_to_local * it.p;
            // Same arithmetic as Dr.Jit's texture (gridvolume), so both plugins
            // pick the same voxels and weights.
            if (m_nearest)
                return value_at(index_add(clamp_voxel(index_floor(p * m_resolution)), m_index_min),
                                active);
            rel = dr::fmadd(p, m_resolution, -.5f);
        } else {
            Point4f p = m_index_from_world * Point4f(it.p.x(), it.p.y(), it.p.z(), 1.f);
            rel = Vector3f(p.x(), p.y(), p.z());
            if (m_nearest)
                return value_at(index_add(clamp_voxel(index_floor(rel + .5f)), m_index_min),
                                active);
        }
        return trilinear_at(clamp_position(rel), active);
    }

    /// count_lookups: adds the active lanes to counter `which` (see
    /// kCounterNames). A benchmarking aid: an atomic add per call.
    void count(int which, const Mask &active) const {
        if (!m_count)
            return;
        if constexpr (dr::is_jit_v<Float>)
            dr::scatter_reduce(ReduceOp::Add, m_counters, UInt64(1), UInt32(which), active);
        else if (active)
            m_scalar_counters[which].fetch_add(1, std::memory_order_relaxed);
    }

    /// A cell the walk entered: counted, by its bound (zero or not) and size
    void count_step(const Walk &walk, const Mask &active) const {
        if (!m_count)
            return;
        count(1, active);
        count(2, active && walk.majorant == 0.f);
        const int32_t dims[4] = { 8, 32, 128, 4096 };
        for (int i = 0; i < 4; ++i)
            count(3 + i, active && walk.hdda.dim == dims[i]);
    }

    static constexpr int kCounters = 8;
    static constexpr const char *kCounterNames[kCounters] = {
        "lookup_count", "walk_step_count", "walk_empty_step_count", "walk_step_8_count",
        "walk_step_32_count", "walk_step_128_count", "walk_step_4096_count", "walk_count"
    };

    std::string counters_string() const {
        if (!m_count)
            return "";
        uint64_t c[kCounters];
        if constexpr (dr::is_jit_v<Float>) {
            dr::eval(m_counters);
            dr::store(c, m_counters);
        } else {
            for (int i = 0; i < kCounters; ++i)
                c[i] = m_scalar_counters[i].load();
        }
        std::string out;
        for (int i = 0; i < kCounters; ++i)
            out += std::string("  ") + kCounterNames[i] + " = " + std::to_string(c[i]) + ",\n";
        return out;
    }

    /// Value stored at integer index coordinate `ijk` (PNanoVDB traversal),
    /// clamped to max()
    Float value_at(const Vector3i &ijk, Mask active) const {
        namespace ndr = nanovdb_drjit;
        ndr::Coord<UInt32> c(ijk.x(), ijk.y(), ijk.z());
        return dr::minimum(m_max, with_type([&](auto type) {
            return m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                return ndr::root_get_value<decltype(type)::value>(buf, root, c, active);
            });
        }));
    }

    /// Trilinear interpolation at index position m_index_min + rel: the 8
    /// corners in one traversal (root_get_stencil_addresses), summed in the
    /// order and with the weights of Dr.Jit's texture
    Float trilinear_at(const Vector3f &rel, Mask active) const {
        namespace ndr = nanovdb_drjit;
        Vector3i base = index_floor(rel);
        Vector3f w1 = rel - Vector3f(base),
                 w0 = 1.f - w1;
        Vector3i ijk0 = index_add(base, m_index_min);
        ndr::Coord<UInt32> c(ijk0.x(), ijk0.y(), ijk0.z());
        Float result = with_type([&](auto type) {
            constexpr uint32_t T = decltype(type)::value;
            // Levels: only the quantized and half readers need them
            constexpr bool with_level = ndr::grid_type_traits<T>::type.codec !=
                                        ndr::layout::LeafCodec::Float32;
            ndr::StencilAddresses<UInt32> corners =
                m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                    return ndr::root_get_stencil<T, with_level>(buf, root, c, active);
                });
            Float sum = 0.f;
            for (uint32_t corner = 0; corner < 8; ++corner) {
                Float weight = 1.f;
                for (uint32_t k = 0; k < 3; ++k)
                    weight = weight * (((corner >> k) & 1) ? w1[k] : w0[k]);
                ndr::Coord<UInt32> ijk = ndr::coord_add<UInt32>(c, corner & 1u, (corner >> 1) & 1u,
                                                                (corner >> 2) & 1u);
                Float value = ndr::root_read_float<T>(grid_words(), corners.address[corner],
                                                      corners.level[corner], ijk, active);
                sum = dr::fmadd(value, weight, sum);
            }
            return sum;
        });
        // The rounded weights can sum to slightly more than 1, so the result
        // could exceed the largest corner by a few ulps (measured: 3 ulps on
        // a level set whose values sit at its maximum); and corners outside
        // the volume's box may hold more than max(). The heterogeneous
        // medium needs max() to be a true bound, so clamp.
        return dr::minimum(result, m_max);
    }

    // ---- Vec3f -------------------------------------------------------------

    /// lookup() for Vec3f grids: the 3-vector, each channel clamped to its max
    Vector3f lookup3(const Interaction3f &it, Mask active) const {
        MI_MASK_ARGUMENT(active);
        count(0, active);
        auto [nearest, ijk, rel] = index_position(it);
        Vector3f v;
        if (nearest) {
            auto [address, level] = vec3_address(ijk, active);
            v = nanovdb_drjit::root_read_vec3f<kVec3f>(grid_words(), address, active);
        } else {
            v = trilinear_sum(rel, active, [&](const UInt32 &address, const UInt32 &,
                                               const nanovdb_drjit::Coord<UInt32> &) {
                return nanovdb_drjit::root_read_vec3f<kVec3f>(grid_words(), address, active);
            });
        }
        return dr::minimum(v, m_max3);
    }

    /// eval() of a Vec3f grid in spectral variants, as gridvolume's
    /// interpolate_spectral: the sRGB-model spectrum of each voxel's
    /// coefficients, interpolated, times the interpolated scale
    UnpolarizedSpectrum lookup_spectral(const Interaction3f &it, Mask active) const {
        namespace ndr = nanovdb_drjit;
        count(0, active);
        auto [nearest, ijk, rel] = index_position(it);
        auto corner_value = [&](const UInt32 &address, const UInt32 &level,
                                const ndr::Coord<UInt32> &c) {
            Vector3f coeff = ndr::root_read_vec3f<kVec3f>(grid_words(), address, active);
            Float scale = value_scale(address, level, c, active);
            return std::make_pair(
                srgb_model_eval<UnpolarizedSpectrum>(coeff, it.wavelengths), scale);
        };
        if (nearest) {
            auto [address, level] = vec3_address(ijk, active);
            ndr::Coord<UInt32> c(ijk.x(), ijk.y(), ijk.z());
            auto [spectrum, scale] = corner_value(address, level, c);
            return spectrum * scale;
        }
        UnpolarizedSpectrum spectrum = trilinear_sum(rel, active, [&](const UInt32 &a, const UInt32 &l,
                                                                     const ndr::Coord<UInt32> &c) {
            return corner_value(a, l, c).first;
        });
        Float scale = trilinear_sum(rel, active, [&](const UInt32 &a, const UInt32 &l,
                                                    const ndr::Coord<UInt32> &c) {
            return value_scale(a, l, c, active);
        });
        return spectrum * dr::minimum(scale, m_max);
    }

    /// The scale of a spectral Vec3f value, found from its address and level
    /// (see to_spectral_coefficients)
    Float value_scale(const UInt32 &address, const UInt32 &level,
                      const nanovdb_drjit::Coord<UInt32> &ijk, const Mask &active) const {
        namespace ndr = nanovdb_drjit;
        constexpr const auto &c = ndr::grid_type_traits<kVec3f>::constants;
        Mask leaf = active & (level == ndr::LEVEL_LEAF),
             entry = active & ((level == ndr::LEVEL_LOWER) | (level == ndr::LEVEL_UPPER)),
             tile = active & (level == ndr::LEVEL_ROOT_TILE),
             background = active & (level == ndr::LEVEL_BACKGROUND);
        UInt32 n = ndr::leaf_coord_to_offset(ijk);
        const dr::divisor<uint32_t> leaf_words(c.leaf_size / 4);
        UInt32 leaf_word = address - (c.leaf_off_table / 4) - 3u * n;
        UInt32 index = leaf_words(UInt32(leaf_word - m_leaf_begin_word)) * 512u + n;
        index = dr::select(tile, m_scale_tiles + ((address - m_tile_begin_word -
                                                   c.root_tile_off_value / 4) >> 3), index);
        index = dr::select(background, m_scale_background, index);
        Float from_array;
        if constexpr (dr::is_jit_v<Float>)
            from_array = dr::gather<Float>(m_scales, index, leaf | tile | background);
        else
            from_array = (leaf | tile | background) ? m_scales[index] : 0.f;
        // Internal tiles keep their scale in the entry's fourth word
        Float from_entry = ndr::read_float(grid_words(), UInt32(address + 3u), entry);
        return dr::select(entry, from_entry, from_array);
    }

    /// Value address and level of voxel ijk in a Vec3f grid
    std::pair<UInt32, UInt32> vec3_address(const Vector3i &ijk, const Mask &active) const {
        namespace ndr = nanovdb_drjit;
        ndr::Coord<UInt32> c(ijk.x(), ijk.y(), ijk.z());
        ndr::AddressAndLevel<UInt32> al =
            m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                return ndr::root_get_value_address_and_level<kVec3f>(buf, root, c, active);
            });
        return { al.address, al.level };
    }

    /// Trilinear interpolation of read(address, level, ijk) over the 8
    /// corners, weights and order as trilinear_at()
    template <typename Read>
    auto trilinear_sum(const Vector3f &rel, const Mask &active, const Read &read) const {
        namespace ndr = nanovdb_drjit;
        Vector3i base = index_floor(rel);
        Vector3f w1 = rel - Vector3f(base), w0 = 1.f - w1;
        Vector3i ijk0 = index_add(base, m_index_min);
        ndr::Coord<UInt32> c(ijk0.x(), ijk0.y(), ijk0.z());
        ndr::StencilAddresses<UInt32> corners =
            m_reader.apply(grid_words(), [&](const auto &buf, const auto &root) {
                return ndr::root_get_stencil<kVec3f, true>(buf, root, c, active);
            });
        decltype(read(UInt32(), UInt32(), c)) sum(0.f);
        for (uint32_t corner = 0; corner < 8; ++corner) {
            Float weight = 1.f;
            for (uint32_t k = 0; k < 3; ++k)
                weight = weight * (((corner >> k) & 1) ? w1[k] : w0[k]);
            ndr::Coord<UInt32> ijk =
                ndr::coord_add<UInt32>(c, corner & 1u, (corner >> 1) & 1u, (corner >> 2) & 1u);
            sum = dr::fmadd(read(corners.address[corner], corners.level[corner], ijk), weight, sum);
        }
        return sum;
    }

    /// Where a lookup reads: (true, voxel) for nearest, (false, -, index
    /// position relative to the box minimum) for trilinear (see lookup())
    std::tuple<bool, Vector3i, Vector3f> index_position(const Interaction3f &it) const {
        if (!m_use_grid_transform) {
            Point3f p = m_to_local * it.p;
            if (m_nearest)
                return { true, index_add(clamp_voxel(index_floor(p * m_resolution)), m_index_min),
                         Vector3f() };
            return { false, Vector3i(), clamp_position(dr::fmadd(p, m_resolution, -.5f)) };
        }
        Point4f p = m_index_from_world * Point4f(it.p.x(), it.p.y(), it.p.z(), 1.f);
        Vector3f rel(p.x(), p.y(), p.z());
        if (m_nearest)
            return { true, index_add(clamp_voxel(index_floor(rel + .5f)), m_index_min),
                     Vector3f() };
        return { false, Vector3i(), clamp_position(rel) };
    }

    /// wrap_mode "clamp" (gridvolume's convention): a voxel (relative to the
    /// box minimum) outside the box is its nearest edge voxel ...
    Vector3i clamp_voxel(const Vector3i &v) const {
        return m_clamp ? dr::clip(v, 0, m_last_voxel) : v;
    }

    /// ... and a trilinear position is kept between the edge voxels' centres:
    /// the same value as clamping each corner of the stencil, as Dr.Jit's
    /// texture does (up to the rounding of weights that sum to 1)
    Vector3f clamp_position(const Vector3f &rel) const {
        return m_clamp ? dr::clip(rel, 0.f, Vector3f(m_last_voxel)) : rel;
    }

    static constexpr uint32_t kVec3f = nanovdb_drjit::layout::GRID_TYPE_VEC3F;

    /// floor() to int32 for positions relative to the box minimum. Points
    /// absurdly far outside the volume are clamped first (a float beyond the
    /// int32 range has no int32 floor); they read the background either way.
    static Vector3i index_floor(const Vector3f &rel) {
        constexpr float limit = 2147483520.f; // largest float below 2^31
        return dr::floor2int<Vector3i>(dr::clip(rel, -limit, limit));
    }

    /// a + b with int32 wrap-around on every backend (the VDB index space
    /// wraps as PNanoVDB's does; plain C++ int32 overflow is undefined)
    static Vector3i index_add(const Vector3i &a, const Vector3i &b) {
        return dr::reinterpret_array<Vector3i>(dr::reinterpret_array<Vector3u>(a) +
                                               dr::reinterpret_array<Vector3u>(b));
    }

    /// Calls fn(std::integral_constant<uint32_t, grid type>) for the grid's
    /// scalar value type (layout.h's visit_value_type): every type is
    /// compiled, one is traced. Vec3f has its own lookups (lookup3).
    template <typename Fn> decltype(auto) with_type(Fn &&fn) const {
        return nanovdb_drjit::layout::visit_value_type<false>(m_grid_type, std::forward<Fn>(fn));
    }

    /// with_type() for the majorant walk, which reads every type's tiles
    template <typename Fn> decltype(auto) with_walk_type(Fn &&fn) const {
        return nanovdb_drjit::layout::visit_value_type(m_grid_type, std::forward<Fn>(fn));
    }

    /// The grid as the translation reads it: a JIT array or a host pointer
    decltype(auto) grid_words() const {
        if constexpr (dr::is_jit_v<Float>)
            return (const UInt32 &) m_grid;
        else
            return static_cast<const uint32_t *>(m_grid.get());
    }

    // =====================================================================
    //  Loading: only the selected grid's bytes, decoded once (the loader's
    //  decode_grid: read -> validate -> value policy -> reader plan) into
    //  one exact-size allocation that the backend owns
    //  (include/nanovdb_drjit/backend_buffer.h). No host copy is kept, and
    //  none is made on LLVM.
    // =====================================================================

    static GridBuffer empty_grid_buffer() {
        if constexpr (dr::is_jit_v<Float>)
            return UInt32();
        else
            return GridBuffer(nullptr, std::free);
    }

    /// Selects, decodes and hands the file's grid to the backend (adopt())
    nanovdb_loader::GridSummary load_grid(const std::string &selector) {
        namespace loader = nanovdb_loader;
        try {
            std::vector<loader::GridEntry> grids = loader::list_grids(m_filename);
            const loader::GridEntry &entry = loader::select_grid(m_filename, grids, selector);
            m_grid_name = entry.name;
            m_grid_type = entry.grid_type;
            m_grid_class = entry.grid_class;
            HostBlock host = allocate(entry.grid_size);
            loader::DecodedGrid decoded = loader::decode_grid(
                m_filename, entry, host.get(), m_backend_bytes, m_invalid_values);
            return adopt(std::move(host), decoded, std::nullopt);
        } catch (const loader::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }
    }

    /// The same for a grid built in memory (memory_source.h); `box`: the
    /// volume's box if it is not the active one
    nanovdb_loader::GridSummary load_bytes(const std::string &name,
                                           const std::vector<uint8_t> &bytes,
                                           const std::optional<nanovdb_loader::IndexBox> &box) {
        namespace loader = nanovdb_loader;
        try {
            m_grid_name = name;
            HostBlock host = allocate(bytes.size());
            loader::DecodedGrid decoded = loader::decode_grid_bytes(
                m_filename, name, bytes.data(), bytes.size(), host.get(), m_backend_bytes,
                m_invalid_values);
            m_grid_type = decoded.grid.summary().grid_type;
            m_grid_class = decoded.grid.summary().grid_class;
            return adopt(std::move(host), decoded, box);
        } catch (const loader::Error &e) {
            Throw("nanovdbvolume: %s", e.what());
        }
    }

    using HostBlock = std::unique_ptr<uint32_t[], void (*)(void *)>;

    /// One host block for `bytes` of grid, padded to 64 bytes: the final
    /// buffer on scalar and LLVM variants (LLVM kernels read host memory in
    /// place), the staging buffer on CUDA
    HostBlock allocate(uint64_t bytes) {
        m_grid_bytes = (size_t) bytes;
        m_backend_bytes = ((m_grid_bytes + 63) / 64) * 64;
        HostBlock host(nullptr, std::free);
        void *ptr = nullptr;
        if (posix_memalign(&ptr, 64, m_backend_bytes) != 0 || !ptr)
            Throw("nanovdbvolume: \"%s\": cannot allocate %zu bytes for grid \"%s\"",
                  m_filename, m_grid_bytes, m_grid_name);
        host.reset((uint32_t *) ptr);
        return host;
    }

    /// A decoded grid in `host`: its bounds (max(), per-node majorants) and
    /// the hand-off to the backend; sets m_grid, m_reader, the value range.
    /// `volume_box`: the volume's box if it is not the active one.
    nanovdb_loader::GridSummary adopt(HostBlock host, const nanovdb_loader::DecodedGrid &decoded,
                                      const std::optional<nanovdb_loader::IndexBox> &volume_box) {
        namespace loader = nanovdb_loader;
        namespace backend = nanovdb_drjit::backend;
        const bool vec3 = m_grid_type == nanovdb_drjit::layout::GRID_TYPE_VEC3F;
        // Spectral variants turn colours into sRGB-model coefficients
        // and a scale, as gridvolume does (unless raw)
        const bool spectral = vec3 && is_spectral_v<Spectrum> && !m_raw;
        const size_t word_count = m_backend_bytes / 4;
        for (const std::string &warning : decoded.warnings)
            Log(Warn, "%s", warning);
        m_reader = Reader::from_plan(decoded.plan);
        loader::GridSummary summary = decoded.grid.summary();
        // max(): what lookups inside the volume can return (its box, and the
        // ring trilinear stencils reach unless they clamp to the box), not
        // every value the grid stores; lookups are clamped to it (lookup())
        m_grid_max_host = decoded.grid.values().max;
        const loader::IndexBox box =
            volume_box ? loader::lookup_box(*volume_box, !m_nearest && !m_clamp)
                       : loader::lookup_box(summary, !m_nearest && !m_clamp);
        m_max_host = loader::max_in_box(decoded.grid, box);
        if (vec3) { // per channel: the clamp of each channel, max_per_channel()
            std::array<float, 3> m = loader::max_in_box_per_channel(decoded.grid, box);
            for (int k = 0; k < 3; ++k)
                m_max3_host[k] = m[k];
        } else {
            m_max3_host = ScalarVector3f(m_max_host);
        }
        // A spectrum is scale * S(coefficients), S in [0, 1], scale =
        // 2 max(rgb): it is bounded by twice the largest channel
        const float spectral_factor = spectral ? 2.f : 1.f;
        if (spectral) {
            m_max_host *= spectral_factor;
            m_grid_max_host *= spectral_factor;
        }
        m_max = dr::opaque<Float>(m_max_host);
        for (int k = 0; k < 3; ++k)
            m_max3[k] = dr::opaque<Float>(m_max3_host[k]);
        m_grid_name = summary.name; // the grid's own name (GridData)
        // Per-node bounds for majorant tracking, raised by 2^-20 for the
        // few ulps by which rounded trilinear weights can overshoot
        loader::NodeMajorants majorants = loader::node_majorants(decoded.grid);
        int32_t base[3];
        for (int k = 0; k < 3; ++k)
            base[k] = summary.empty ? 0 : int32_t(uint32_t(summary.bbox_min[k]) & ~4095u);
        m_majorants = nanovdb_drjit::MajorantGrid<UInt32>::make(
            majorants.layout, majorants.values, (1.f + 0x1p-20f) * spectral_factor,
            m_max_host, base);
        if (m_clamp) { // (walk cells outside the box: see MajorantGrid)
            const loader::IndexBox vb = volume_box ? *volume_box : loader::lookup_box(summary, false);
            int32_t lo[3], hi[3];
            for (int k = 0; k < 3; ++k) {
                lo[k] = int32_t(uint32_t(vb.lo[k]) - uint32_t(base[k]));
                hi[k] = int32_t(uint32_t(vb.hi[k]) - uint32_t(base[k]));
            }
            m_majorants.set_clamp_box(lo, hi, m_max_host);
        }
        m_majorant_bytes = (size_t) majorants.bytes();
        const double mean = spectral_factor * loader::mean_bound(
            decoded.grid, majorants, box, m_max_host / spectral_factor);
        m_majorant_ratio = m_max_host > 0.f ? ScalarFloat(mean / m_max_host) : 1.f;
        for (int k = 0; k < 3; ++k)
            m_cell_base_host[k] = base[k];

        if (spectral)
            to_spectral_coefficients(decoded.grid, summary);

        if constexpr (!dr::is_jit_v<Float>) {
            m_grid = std::move(host);
        } else if constexpr (dr::backend_v<Float> == JitBackend::LLVM) {
            m_grid = UInt32::steal(backend::map_host_words(host.release(), word_count));
        } else {
            try {
                m_grid = UInt32::steal(backend::upload_cuda_words(host.get(), word_count));
            } catch (const std::exception &e) {
                Throw("nanovdbvolume: \"%s\": grid \"%s\" (%zu bytes): %s", m_filename,
                      m_grid_name, m_grid_bytes, e.what());
            }
        }
        return summary;
    }

    /**
     * Spectral variants, Vec3f grids (raw=false): gridvolume turns each
     * voxel's colour into sRGB-model coefficients of rgb / scale and a scale
     * = 2 max(rgb), 4 floats instead of 3. Here the coefficients replace the
     * colour in place, so the tree is not copied, and the scales go where
     * the grid has room: an internal node's table entry is 16 bytes for 12
     * of value (its fourth word), and the others (leaf values, root tiles,
     * the background) into one array beside the grid, indexed from the
     * value's address: 4 bytes per leaf voxel, +33 % of the leaf bytes (the
     * price of the fourth number, as for gridvolume). No colour is kept.
     */
    void to_spectral_coefficients(const nanovdb_loader::ValidatedGrid &grid,
                                  const nanovdb_loader::GridSummary &s) {
        namespace L = nanovdb_drjit::layout;
        constexpr const L::GridTypeConstants &c = L::GRID_TYPE_CONSTANTS_VEC3F;
        uint8_t *buf = const_cast<uint8_t *>(grid.data()); // the upload buffer, ours
        auto convert = [](uint8_t *p) {
            float rgb[3];
            std::memcpy(rgb, p, 12);
            ScalarColor3f color(rgb[0], rgb[1], rgb[2]);
            float scale = dr::max(color) * 2.f;
            ScalarColor3f norm = color / dr::maximum(1e-8f, scale);
            dr::Array<float, 3> coeff = srgb_model_fetch(norm);
            for (int k = 0; k < 3; ++k)
                std::memcpy(p + 4 * k, &coeff[k], 4);
            return scale;
        };
        const uint64_t leaves = s.node_count[0];
        std::vector<float> scales(size_t(leaves) * 512 + s.root_tile_count + 1, 0.f);
        for (uint64_t n = 0; n < leaves; ++n)
            for (uint32_t v = 0; v < 512; ++v)
                scales[size_t(n * 512 + v)] =
                    convert(buf + grid.leaf_byte(n) + c.leaf_off_table + 12 * v);
        auto internal = [&](int level, uint64_t table_off, uint64_t mask_off, uint32_t entries,
                            uint64_t size) {
            for (uint64_t n = 0; n < s.node_count[level]; ++n) {
                uint8_t *node = buf + s.node_begin[level] + n * size;
                for (uint32_t e = 0; e < entries; ++e) {
                    uint32_t mask;
                    std::memcpy(&mask, node + mask_off + 4 * (e >> 5), 4);
                    if ((mask >> (e & 31)) & 1u)
                        continue; // a child offset
                    float scale = convert(node + table_off + 16 * uint64_t(e));
                    std::memcpy(node + table_off + 16 * uint64_t(e) + 12, &scale, 4);
                }
            }
        };
        internal(2, c.upper_off_table, L::UPPER_OFF_CHILD_MASK, L::UPPER_TABLE_COUNT, c.upper_size);
        internal(1, c.lower_off_table, L::LOWER_OFF_CHILD_MASK, L::LOWER_TABLE_COUNT, c.lower_size);
        const uint64_t root = uint64_t(s.root_word) * 4;
        for (uint32_t t = 0; t < s.root_tile_count; ++t)
            scales[size_t(leaves * 512 + t)] =
                convert(buf + root + c.root_size + uint64_t(t) * c.root_tile_size +
                        c.root_tile_off_value);
        scales.back() = convert(buf + root + c.root_off_background);

        m_scale_bytes = scales.size() * sizeof(float);
        m_scale_tiles = dr::opaque<UInt32>(uint32_t(leaves * 512));
        m_scale_background = dr::opaque<UInt32>(uint32_t(scales.size() - 1));
        m_leaf_begin_word = dr::opaque<UInt32>(uint32_t(s.node_begin[0] / 4));
        m_tile_begin_word = dr::opaque<UInt32>(uint32_t(root / 4 + c.root_size / 4));
        if constexpr (dr::is_jit_v<Float>)
            m_scales = dr::load<Float>(scales.data(), scales.size());
        else
            m_scales = std::move(scales);
    }

    /// The active index box [min, max] (inclusive) becomes the volume's
    /// extent. An empty grid reads as the single voxel at the origin, i.e.
    /// its background everywhere.
    void set_index_box(const nanovdb_loader::GridSummary &summary,
                       const std::optional<nanovdb_loader::IndexBox> &box) {
        m_background_host = summary.background;
        ScalarVector3i bmin(summary.bbox_min[0], summary.bbox_min[1], summary.bbox_min[2]),
                       bmax(summary.bbox_max[0], summary.bbox_max[1], summary.bbox_max[2]);
        if (summary.empty)
            bmin = bmax = ScalarVector3i(0);
        if (box) { // a dense source: its whole box, active or not
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
        }
        // Per-file values reach kernels as opaque variables, so that loading
        // another file does not recompile them.
        for (int k = 0; k < 3; ++k) {
            m_index_min[k]  = dr::opaque<Int32>(bmin[k]);
            m_resolution[k] = dr::opaque<Float>((ScalarFloat) m_resolution_host[k]);
            m_last_voxel[k] = dr::opaque<Int32>(m_resolution_host[k] - 1);
        }
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
        {
            for (int corner = 0; corner < 8; ++corner) {
                double idx[3];
                for (int k = 0; k < 3; ++k)
                    idx[k] = (corner >> k & 1)
                                 ? m_index_min_host[k] + m_resolution_host[k] - 0.5
                                 : m_index_min_host[k] - 0.5;
                ScalarPoint3f world;
                for (int r = 0; r < 3; ++r) {
                    double w = summary.map_vec[r];
                    for (int c = 0; c < 3; ++c)
                        w += summary.map_mat[3 * r + c] * idx[c];
                    world[r] = (float) w;
                }
                bb.expand(world);
            }
        }
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
        // index = inv_mat * (world - vec); relative to the box minimum:
        // rel = inv_mat * world - (inv_mat * vec + min), composed with
        // to_local in double precision and rounded once.
        using Matrix4d = dr::Matrix<double, 4>;
        Matrix4d index_from_grid = dr::identity<Matrix4d>();
        for (int r = 0; r < 3; ++r) {
            double t = 0.0;
            for (int c = 0; c < 3; ++c) {
                index_from_grid(r, c) = summary.map_inv[3 * r + c];
                t += summary.map_inv[3 * r + c] * summary.map_vec[c];
            }
            index_from_grid(r, 3) = -t - (double) m_index_min_host[r];
        }
        Matrix4d to_local = dr::identity<Matrix4d>();
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                to_local(r, c) = (double) m_to_local.matrix(r, c);
        Matrix4d m = index_from_grid * to_local;
        m_index_from_world_host = m;
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_index_from_world(r, c) = dr::opaque<Float>((ScalarFloat) m(r, c));

        // World-space bounds: the voxels' cells [min - 0.5, max + 0.5] of the
        // index box, mapped by the grid transform and then by to_world.
        ScalarAffineTransform4f to_world = m_to_local.inverse();
        m_bbox = ScalarBoundingBox3f();
        for (int corner = 0; corner < 8; ++corner) {
            double idx[3], world[3];
            for (int k = 0; k < 3; ++k)
                idx[k] = (corner >> k & 1)
                             ? m_index_min_host[k] + m_resolution_host[k] - 0.5
                             : m_index_min_host[k] - 0.5;
            for (int r = 0; r < 3; ++r) {
                world[r] = summary.map_vec[r];
                for (int c = 0; c < 3; ++c)
                    world[r] += summary.map_mat[3 * r + c] * idx[c];
            }
            m_bbox.expand(to_world * ScalarPoint3f((float) world[0], (float) world[1],
                                                   (float) world[2]));
        }
    }

    /// World -> cell space of the majorant walk, composed in double and
    /// rounded once: the index position of a lookup (relative to the box
    /// minimum, values at integers), + 0.5 (voxel ijk covers [ijk, ijk + 1)),
    /// + the box minimum - the walk's base
    void set_cell_transform(const nanovdb_loader::GridSummary &) {
        using Matrix4d = dr::Matrix<double, 4>;
        Matrix4d m = dr::identity<Matrix4d>();
        if (m_use_grid_transform) {
            m = m_index_from_world_host;
            for (int r = 0; r < 3; ++r)
                m(r, 3) += 0.5;
        } else {
            // rel + 0.5 = local * resolution (see lookup())
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c)
                    m(r, c) = (double) m_to_local.matrix(r, c) * (double) m_resolution_host[r];
        }
        for (int r = 0; r < 3; ++r)
            m(r, 3) += double(int64_t(m_index_min_host[r]) - int64_t(m_cell_base_host[r]));
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c)
                m_cell_from_world(r, c) = dr::opaque<Float>((ScalarFloat) m(r, c));
    }

private:
    // Backend (JIT variables, opaque per file; plain values on scalars)
    GridBuffer m_grid;            // the grid's 32-bit words
    Reader m_reader;              // readers chosen by the loader's plan
    Vector3i m_index_min;         // active box minimum
    Vector3f m_resolution;        // active box extent in voxels, as Float
    Vector3i m_last_voxel;        // extent - 1 (wrap_mode "clamp")
    Matrix4f m_index_from_world;  // use_grid_transform: world -> index - min
    Float m_max;                  // max(), the clamp of trilinear results
    Vector3f m_max3;              // Vec3f: the clamp of each channel
    ScalarGridScales m_scales;    // spectral Vec3f: each value's scale (see to_spectral_coefficients)
    UInt32 m_scale_tiles, m_scale_background; // ... where root tiles' and the background's scales start
    UInt32 m_leaf_begin_word, m_tile_begin_word; // ... the leaf array and the root tiles
    nanovdb_drjit::MajorantGrid<UInt32> m_majorants; // per-node bounds (majorant walk)
    Matrix4f m_cell_from_world;   // world -> the walk's cell space

    // Host
    ScalarVector3i m_index_min_host;
    ScalarVector3i m_resolution_host;
    ScalarFloat m_max_host = 0.f;      // max(): the largest value lookups in the box return
    ScalarFloat m_grid_max_host = 0.f; // the largest value the grid stores
    ScalarVector3f m_max3_host;        // Vec3f: max() per channel (max_per_channel)
    size_t m_scale_bytes = 0;          // spectral Vec3f: the scales beside the grid
    bool m_raw = false;                // Vec3f: no spectral conversion
    ScalarFloat m_background_host = 0.f;
    uint32_t m_grid_type = 0;     // NanoVDB's GridType (layout.h)
    uint32_t m_grid_class = 0;    // NanoVDB's GridClass (level set, fog volume, ...)
    size_t m_grid_bytes = 0;      // the grid's bytes
    size_t m_backend_bytes = 0;   // what the backend holds for it (padded to 64 B)
    size_t m_majorant_bytes = 0;  // the per-node bounds beside it
    ScalarFloat m_majorant_ratio = 1.f; // their mean over the volume / max()
    int32_t m_cell_base_host[3] = { 0, 0, 0 };       // the walk's base (multiple of 4096)
    dr::Matrix<double, 4> m_index_from_world_host;   // use_grid_transform, in double
    bool m_nearest = false;
    bool m_clamp = false;                        // wrap_mode "clamp": positions clamped to the box
    bool m_use_grid_transform = false;
    bool m_count = false;                        // count_lookups
    mutable UInt64 m_counters;                   // ... JIT: lookups, walk steps
    mutable std::atomic<uint64_t> m_scalar_counters[kCounters] = {}; // ... scalar
    nanovdb_loader::InvalidValues m_invalid_values = nanovdb_loader::InvalidValues::Error;
    std::string m_filename, m_grid_name;

    MI_TRAVERSE_CB(Base, m_grid, m_reader.root, m_reader.root_table, m_reader.block_min,
                   m_reader.block_dims, m_index_min, m_resolution, m_last_voxel,
                   m_index_from_world, m_max,
                   m_majorants.table, m_majorants.leaf_begin, m_majorants.lower_begin,
                   m_majorants.upper_begin, m_majorants.tile_begin, m_majorants.lower_slot,
                   m_majorants.upper_slot, m_majorants.tile_slot, m_majorants.background,
                   m_majorants.clamp, m_majorants.base, m_majorants.box_lo, m_majorants.box_hi,
                   m_majorants.outside, m_cell_from_world, m_max3, m_scales,
                   m_scale_tiles, m_scale_background, m_leaf_begin_word, m_tile_begin_word)
};

MI_EXPORT_PLUGIN(NanoVDBVolume)
NAMESPACE_END(mitsuba)
