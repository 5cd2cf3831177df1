#!/usr/bin/env python3
"""Independent reference for NanoVDB OnIndex grids with values in blind data.

What it does
------------
For every grid of a NanoVDB file made of OnIndex (index) grids whose
per-voxel values live in a blind-data channel (fVDB style, e.g.
``fvdb_jdatafloat32``), this script

* loads the grid with NVIDIA Warp (``wp.Volume.load_from_nvdb`` for the
  first grid, ``Volume.load_next_grid()`` for the following ones) and
  cross-checks it against a Volume built from the grid bytes that this
  script decompresses itself (``wp.Volume(wp.array(raw_bytes))``);
* lists the active voxels with ``Volume.get_voxels()`` and looks up each
  voxel's index with ``wp.volume_lookup_index`` in a CPU kernel.
  NOTE: Warp returns ``nanovdb_value_index - 1`` (so -1 for the background
  / inactive voxels); this script adds 1 back, so the indices it writes are
  NanoVDB value indices (0 = background, active voxels 1..N);
* probes inactive coordinates (just outside the active bounding box, and
  inside it but inactive) and checks that their NanoVDB index is 0;
* recomputes every active voxel's index with its own parser of the leaf
  nodes (mOffset + popcount of the value mask below the voxel) and checks
  that indices 1..N follow NanoVDB's leaf order;
* parses the grid's blind metadata itself (GridData offset 640/648,
  288-byte GridBlindMetaData records), reads the blind channel (an int64
  header [ndim, N, d1, d2, ...] followed by N*d1*d2*... float32 values),
  asserts that N equals the active voxel count, and that it matches Warp's
  ``Volume.feature_array()`` bytes. Row r of the tensor belongs to value
  index r + 1.

The result is written as JSON (one line per voxel). That JSON is committed
(tests/data/warp_onindex_reference.json) so that the project's tests do not
need Warp.

How to run
----------
Needs ``warp-lang`` (tested with 1.19.0, CPU only) and numpy::

    pip install warp-lang==1.19.0          # or: pip install --target DIR ...
    python3 tools/warp_onindex_reference.py \
        [INPUT.nvdb] [OUTPUT.json]

Defaults: /work/shared/data/warp_onindex_2grids_zip_32.6.1.nvdb and
tests/data/warp_onindex_reference.json (relative to the repository root).
"""

import json
import os
import struct
import sys
import zlib

import numpy as np
import warp as wp

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_IN = "/work/shared/data/warp_onindex_2grids_zip_32.6.1.nvdb"
DEFAULT_OUT = os.path.join(REPO, "tests", "data", "warp_onindex_reference.json")

GRID_TYPE_ONINDEX = 20
LEAF_ONINDEX_SIZE = 96  # bbox min (12) + bbox dif (3) + flags (1) + mask (64) + mOffset (8) + mPrefixSum (8)


# ---------------------------------------------------------------- file layer
def split_file(data):
    """Return [(name, raw_grid_bytes)] for every grid of every segment."""
    grids = []
    pos = 0
    while pos < len(data):
        magic, version, grid_count, codec = struct.unpack_from("<QIHH", data, pos)
        assert data[pos : pos + 7] == b"NanoVDB", "bad segment magic"
        assert version >> 21 == 32, f"major version {version >> 21}"
        pos += 16
        metas = []
        for _ in range(grid_count):
            grid_size, file_size = struct.unpack_from("<QQ", data, pos)
            (name_size,) = struct.unpack_from("<I", data, pos + 136)
            name = data[pos + 176 : pos + 176 + name_size].rstrip(b"\0").decode()
            metas.append((name, grid_size, file_size))
            pos += 176 + name_size
        for name, grid_size, file_size in metas:
            if codec == 0:
                raw = data[pos : pos + grid_size]
            elif codec == 1:
                (csize,) = struct.unpack_from("<Q", data, pos)
                raw = zlib.decompress(data[pos + 8 : pos + 8 + csize])
            else:
                raise RuntimeError(f"codec {codec} not handled")
            assert len(raw) == grid_size
            grids.append((name, raw))
            pos += file_size
    return grids


# ---------------------------------------------------------------- own parser
def parse_grid(raw):
    g = {}
    g["grid_class"], g["grid_type"] = struct.unpack_from("<II", raw, 632)
    g["blind_off"], g["blind_count"] = struct.unpack_from("<qI", raw, 640)
    g["data1"], g["data2"] = struct.unpack_from("<QQ", raw, 656)
    tree = 672
    offs = struct.unpack_from("<4Q", raw, tree)  # leaf, lower, upper, root (relative to tree)
    g["node_count"] = struct.unpack_from("<3I", raw, tree + 32)
    g["tile_count"] = struct.unpack_from("<3I", raw, tree + 44)
    (g["tree_voxel_count"],) = struct.unpack_from("<Q", raw, tree + 56)
    leaves = []
    for li in range(g["node_count"][0]):
        a = tree + offs[0] + li * LEAF_ONINDEX_SIZE
        bbox_min = struct.unpack_from("<3i", raw, a)  # min of the active voxels, not the origin
        origin = tuple(c & ~7 for c in bbox_min)
        words = struct.unpack_from("<8Q", raw, a + 16)
        offset, prefix = struct.unpack_from("<QQ", raw, a + 80)
        leaves.append((origin, words, offset, prefix))
    g["leaves"] = leaves
    blind = []
    for b in range(g["blind_count"]):
        a = g["blind_off"] + 288 * b
        data_off, value_count, value_size, semantic, data_class, data_type = struct.unpack_from("<qQIIII", raw, a)
        name = raw[a + 32 : a + 288].split(b"\0")[0].decode()
        start = a + data_off
        blind.append(
            dict(
                name=name,
                value_count=value_count,
                value_size=value_size,
                semantic=semantic,
                data_class=data_class,
                data_type=data_type,
                bytes=raw[start : start + value_count * value_size],
            )
        )
    g["blind"] = blind
    return g


def own_value_index(leaf, ijk):
    """NanoVDB OnIndex value index of ijk inside this leaf (0 if inactive)."""
    origin, words, offset, _prefix = leaf
    n = ((ijk[0] & 7) << 6) | ((ijk[1] & 7) << 3) | (ijk[2] & 7)
    w, bit = n >> 6, n & 63
    if not (words[w] >> bit) & 1:
        return 0
    below = sum(bin(words[i]).count("1") for i in range(w)) + bin(words[w] & ((1 << bit) - 1)).count("1")
    return offset + below


def leaf_order_voxels(g):
    """Active voxels in NanoVDB leaf order: leaf by leaf, offset n ascending."""
    out = []
    for leaf in g["leaves"]:
        origin, words = leaf[0], leaf[1]
        for n in range(512):
            if (words[n >> 6] >> (n & 63)) & 1:
                out.append((origin[0] + (n >> 6), origin[1] + ((n >> 3) & 7), origin[2] + (n & 7)))
    return out


# ---------------------------------------------------------------- Warp side
@wp.kernel
def lookup_kernel(vid: wp.uint64, coords: wp.array(dtype=wp.vec3i), out: wp.array(dtype=wp.int32)):
    t = wp.tid()
    c = coords[t]
    out[t] = wp.volume_lookup_index(vid, c[0], c[1], c[2])


def warp_lookup(volume, coords):
    c = wp.array(np.asarray(coords, dtype=np.int32).reshape(-1, 3), dtype=wp.vec3i, device="cpu")
    out = wp.zeros(len(coords), dtype=wp.int32, device="cpu")
    wp.launch(lookup_kernel, dim=len(coords), inputs=[volume.id, c, out], device="cpu")
    return out.numpy().astype(np.int64) + 1  # Warp returns NanoVDB index - 1


def fmt_f32(x):
    return np.format_float_positional(np.float32(x), unique=True, trim="-")


def main():
    path_in = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_IN
    path_out = sys.argv[2] if len(sys.argv) > 2 else DEFAULT_OUT
    wp.config.quiet = True
    wp.init()

    data = open(path_in, "rb").read()
    raw_grids = split_file(data)

    # Warp's own file loader: first grid, then load_next_grid() for the rest.
    warp_vols = [wp.Volume.load_from_nvdb(data, device="cpu")]
    while len(warp_vols) < len(raw_grids):
        nxt = warp_vols[-1].load_next_grid()
        assert nxt is not None
        warp_vols.append(nxt)
    assert warp_vols[-1].load_next_grid() is None

    result = {
        "source": os.path.basename(path_in),
        "generator": f"tools/warp_onindex_reference.py, warp-lang {wp.config.version}",
        "index_convention": "NanoVDB value index: 0 = background/inactive, active voxels 1..N; "
        "blind tensor row r = value index r+1 (wp.volume_lookup_index returns index-1)",
        "grids": [],
    }

    keep = []
    for gi, ((name, raw), vol) in enumerate(zip(raw_grids, warp_vols)):
        info = vol.get_grid_info()
        assert info.name == name and info.type_str == "OnIndex" and vol.is_index
        # the same grid, built from the bytes decompressed here
        raw_np = np.frombuffer(raw, dtype=np.uint8).copy()
        vol_own = wp.Volume(wp.array(raw_np, dtype=wp.uint8, device="cpu"))
        keep.append(vol_own)

        g = parse_grid(raw)
        assert g["grid_type"] == GRID_TYPE_ONINDEX

        n_vox = vol.get_voxel_count()
        voxels = vol.get_voxels().numpy()  # row r = voxel with NanoVDB index r+1
        assert voxels.shape == (n_vox, 3)
        assert np.array_equal(voxels, vol_own.get_voxels().numpy())

        idx = warp_lookup(vol, voxels)
        assert np.array_equal(idx, warp_lookup(vol_own, voxels))
        assert np.array_equal(idx, np.arange(1, n_vox + 1)), idx
        assert n_vox == g["tree_voxel_count"]

        # own leaf parser: same indices, and indices follow the leaf order
        leaf_of = {tuple(l[0]): l for l in g["leaves"]}
        own = [own_value_index(leaf_of[tuple(int(c) & ~7 for c in v)], v) for v in voxels.tolist()]
        assert own == idx.tolist()
        leaf_order = leaf_order_voxels(g)
        in_leaf_order = [tuple(v) for v in voxels.tolist()] == leaf_order
        assert in_leaf_order
        tiles = vol.get_tiles().numpy().tolist()
        assert tiles == [list(l[0]) for l in g["leaves"]]

        # inactive probes
        lo, hi = voxels.min(axis=0), voxels.max(axis=0)
        active = set(map(tuple, voxels.tolist()))
        outside = [
            (int(x), int(y), int(z))
            for x in (lo[0] - 1, hi[0] + 1)
            for y in (lo[1] - 1, hi[1] + 1)
            for z in (lo[2] - 1, hi[2] + 1)
        ]
        inside = []
        # 4 inactive voxels inside allocated leaves (lookup reaches level 0) ...
        for origin, *_ in g["leaves"]:
            for d in ((0, 0, 0), (7, 7, 7), (3, 4, 5), (1, 2, 3)):
                p = tuple(origin[a] + d[a] for a in range(3))
                if p not in active and all(lo[a] <= p[a] <= hi[a] for a in range(3)) and p not in inside:
                    inside.append(p)
                    break
            if len(inside) == 4:
                break
        # ... and 4 inside the bbox where no leaf exists
        leaf_origins = set(leaf_of)
        for p in ((0, 0, 0), tuple(int(v) for v in (lo + hi) // 2), tuple(int(v) for v in lo), tuple(int(v) for v in hi),
                  (int(lo[0]), int(hi[1]), int(lo[2])), (int(hi[0]), int(lo[1]), int(hi[2])),
                  (int(lo[0]), int(lo[1]), int(hi[2])), (int(hi[0]), int(hi[1]), int(lo[2]))):
            if len(inside) == 8:
                break
            if p not in active and tuple(c & ~7 for c in p) not in leaf_origins and p not in inside:
                inside.append(p)
        probes = outside + inside
        pidx = warp_lookup(vol, probes)
        assert np.all(pidx == 0), pidx
        assert all(own_value_index(leaf_of[tuple(c & ~7 for c in p)], p) == 0 for p in probes
                   if tuple(c & ~7 for c in p) in leaf_of)

        # blind channel: own parser vs Warp's feature_array
        chans = [b for b in g["blind"] if b["name"].startswith("fvdb_jdata")]
        assert len(chans) == 1
        ch = chans[0]
        winfo = vol.get_feature_array_info(g["blind"].index(ch))
        assert winfo.name == ch["name"] and winfo.value_count == ch["value_count"]
        wbytes = vol.feature_array(g["blind"].index(ch), dtype=wp.uint8).numpy().tobytes()
        assert wbytes == ch["bytes"]
        b = ch["bytes"]
        ndim, = struct.unpack_from("<q", b, 0)
        header = list(struct.unpack_from(f"<{ndim + 1}q", b, 0))
        shape = header[1:]
        hdr_bytes = 8 * (ndim + 1)
        assert shape[0] == n_vox, (shape, n_vox)
        row = int(np.prod(shape[1:]))
        vals = np.frombuffer(b, dtype="<f4", offset=hdr_bytes, count=shape[0] * row).reshape(shape[0], row)
        assert hdr_bytes + vals.nbytes == len(b)

        lines = []
        for r, (v, ix) in enumerate(zip(voxels.tolist(), idx.tolist())):
            lines.append([*v, ix, *vals[ix - 1].tolist()])
        result["grids"].append(
            dict(
                grid_index=gi,
                name=name,
                grid_type="OnIndex",
                active_voxel_count=n_vox,
                griddata_value_count=g["data1"],
                leaf_count=len(g["leaves"]),
                node_count_leaf_lower_upper=list(g["node_count"]),
                tree_tile_count_field=list(g["tile_count"]),
                active_bbox=[lo.tolist(), hi.tolist()],
                background_index=0,
                indices_in_leaf_order=in_leaf_order,
                leaf_origins=tiles,
                blind=dict(
                    name=ch["name"],
                    value_size=ch["value_size"],
                    value_count=ch["value_count"],
                    semantic=ch["semantic"],
                    data_class=ch["data_class"],
                    data_type=ch["data_type"],
                    header=header,
                    header_bytes=hdr_bytes,
                    row_floats=row,
                ),
                voxels=lines,
                inactive_probes=[[*p, 0] for p in probes],
            )
        )

    write_json(result, path_out)
    for gr in result["grids"]:
        print(gr["name"], gr["active_voxel_count"], gr["active_bbox"], gr["blind"]["header"])


def write_json(result, path):
    """JSON with one voxel / probe per line; floats in shortest float32 form."""

    def row(r, nint):
        return "[" + ", ".join([str(int(x)) for x in r[:nint]] + [fmt_f32(x) for x in r[nint:]]) + "]"

    out = ["{"]
    for key in ("source", "generator", "index_convention"):
        out.append(f"  {json.dumps(key)}: {json.dumps(result[key])},")
    out.append('  "grids": [')
    for n, g in enumerate(result["grids"]):
        out.append("    {")
        for key, val in g.items():
            if key in ("voxels", "inactive_probes"):
                continue
            out.append(f"      {json.dumps(key)}: {json.dumps(val)},")
        out.append('      "voxels_columns": ["i", "j", "k", "value_index", "row floats..."],')
        out.append('      "voxels": [')
        out.append(",\n".join("        " + row(r, 4) for r in g["voxels"]))
        out.append("      ],")
        out.append('      "inactive_probes": [')
        out.append(",\n".join("        " + row(r, 4) for r in g["inactive_probes"]))
        out.append("      ]")
        out.append("    }" + ("," if n + 1 < len(result["grids"]) else ""))
    out.append("  ]")
    out.append("}")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")
    json.load(open(path))  # must parse


if __name__ == "__main__":
    main()
