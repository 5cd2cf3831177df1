// vdb2nvdb's pipelines: read, prepare, convert, write, read back, verify,
// export, commit. See convert.h.

#include "convert.h"

#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>

#include <nanovdb_convert/format.h>
#include <nanovdb_convert/handle.h>
#include <nanovdb_convert/prepare.h>
#include <nanovdb_convert/to_nano.h>
#include "dense.h"
#include "describe.h"
#include "read.h"
#include "report.h"
#include "temp_file.h"
#include "verify.h"

namespace vdb2nvdb {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

double ms_since(Clock::time_point t0) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// A file name made of a grid name: [A-Za-z0-9._-], others become '_'.
std::string safe_name(const std::string &name, size_t index) {
    if (name.empty())
        return "grid" + std::to_string(index);
    std::string s = name;
    for (char &c : s)
        if (!std::isalnum((unsigned char) c) && c != '.' && c != '-' && c != '_')
            c = '_';
    return s;
}

} // namespace

int convert_grids(openvdb::GridPtrVec all, const std::string &label, const std::string &out,
                  const Options &opts) {
    // Create the output first: an unwritable path fails before any work
    TempFile out_tmp(out);
    std::vector<Prepared> grids = select_and_prepare(all, label, opts);

    // Dense exports: sizes checked before anything is converted
    std::vector<std::unique_ptr<TempFile>> dense_tmps;
    std::vector<DenseBox> dense_boxes;
    if (!opts.dense.empty()) {
        const uint64_t limit = dense_limit(opts);
        for (size_t i = 0; i < grids.size(); ++i) {
            DenseBox d = dense_box(grids[i].base().evalActiveVoxelBoundingBox());
            d.channels = grids[i].vec ? 3 : 1;
            if (d.bytes() > limit)
                throw Error("--dense: grid " + dq(grids[i].name) + " would need " +
                            fmt_bytes(d.bytes()) + " dense (" + fmt_count(d.voxels()) +
                            " voxels), more than the limit of " + fmt_bytes(limit) +
                            (opts.max_dense_bytes ? " (--max-dense-bytes)"
                                                  : " (half the physical memory; raise it with "
                                                    "--max-dense-bytes)"));
            dense_boxes.push_back(d);
        }
        std::set<std::string> used;
        for (size_t i = 0; i < grids.size(); ++i) {
            std::string path = opts.dense;
            if (grids.size() > 1) {
                // OUT.vol -> OUT_<grid>.vol, one file per grid (OUT_<grid>_<index>.vol
                // for a repeated name)
                fs::path p(opts.dense);
                std::string stem = p.stem().string(), ext = p.extension().string();
                if (ext.empty())
                    ext = ".vol";
                std::string tag = safe_name(grids[i].name, i);
                if (!used.insert(tag).second)
                    tag += "_" + std::to_string(i);
                path = (p.parent_path() / (stem + "_" + tag + ext)).string();
            }
            dense_tmps.push_back(std::make_unique<TempFile>(path));
        }
    }

    // Convert and write, one grid (one segment) at a time
    std::vector<GridReport> reports;
    {
        std::ofstream os(out_tmp.tmp_path(), std::ios::binary | std::ios::trunc);
        if (!os)
            throw Error("cannot write " + dq(out) + ": " + std::strerror(errno));
        for (Prepared &p : grids) {
            auto t0 = Clock::now();
            Handle h;
            if (p.vec) {
                if (opts.quantize != Quantize::Float)
                    note("grid " + dq(p.name) + " (vec3s) is written as Vec3f: --quantize "
                         "applies to float grids");
                h = convert_vec3(*p.vec);
            } else {
                const Quantize q = effective_quantize(*p.grid, opts.quantize);
                if (q != opts.quantize)
                    note("grid " + dq(p.name) + " has no leaf nodes: written as fp16 instead of "
                         "fpn (NanoVDB 32.4's FpN encoder needs a leaf); it holds no quantized "
                         "values");
                h = convert_one(*p.grid, q, opts);
                if (opts.corrupt_for_test)
                    corrupt_for_test(h);
            }
            GridReport r = report_of(h);
            r.name = p.name;
            if (opts.stats) // as written: after a level set's fog conversion
                r.details = grid_details(p.base(), p.base().evalActiveVoxelBoundingBox());
            r.cls = class_name(p.base().getGridClass());
            try {
                nanovdb::io::writeGrid(os, h, opts.codec);
            } catch (const std::exception &e) {
                throw Error("cannot write " + dq(out) + ": " + e.what());
            }
            if (!os)
                throw Error("error writing " + dq(out) + " (disk full?)");
            r.convert_ms = ms_since(t0);
            say(opts, "converted " + dq(p.name) +
                          (p.fogged ? " (level set -> fog volume)" : "") + ": " +
                          fmt_count(r.active) + " active voxels, " + r.type + ", " +
                          fmt_bytes(r.grid_bytes) + ", " + fmt_float(std::round(r.convert_ms)) + " ms");
            reports.push_back(std::move(r));
        }
        os.close();
        if (os.fail())
            throw Error("error writing " + dq(out) + " (disk full?)");
    }
    const uint64_t file_size = fs::file_size(out_tmp.tmp_path());

    // Read the file back from disk with NanoVDB's reader: verify, dense, probes
    bool ok = true;
    if (opts.verify > 0 || !opts.dense.empty() || !opts.probes.empty()) {
        for (size_t i = 0; i < grids.size(); ++i) {
            Handle h;
            try {
                h = nanovdb::io::readGrid<nanovdb::HostBuffer>(out_tmp.tmp_path(), uint64_t(i));
            } catch (const std::exception &e) {
                throw Error("cannot read back the written file " + dq(out) + ": " + e.what(),
                            ExitVerify);
            }
            if (grids[i].vec) {
                const auto *nano = h.grid<nanovdb::Vec3f>();
                if (!nano)
                    throw Error("grid " + dq(grids[i].name) + " in the written file is not Vec3f",
                                ExitVerify);
                if (opts.verify > 0)
                    ok = verify_vec3(*grids[i].vec, *nano, grids[i].name, opts) && ok;
            } else if (opts.verify > 0) {
                ok = verify_float(*grids[i].grid, h, grids[i].name, opts) && ok;
            }
            if (ok && !opts.dense.empty()) {
                write_dense(h, grids[i].name, grids[i].base().transform(), dense_boxes[i],
                            dense_tmps[i]->tmp_path());
                say(opts, "dense export of " + dq(grids[i].name) + ": " + dense_tmps[i]->path());
            }
            if (!grids[i].vec && ok && !opts.probes.empty()) // probes: float grids
                print_probes(*grids[i].grid, h, grids[i].name, opts);
        }
    }
    if (!ok) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: verification failed; %s was not written\n",
                     out.c_str());
        return ExitVerify;
    }
    out_tmp.commit();
    for (auto &t : dense_tmps)
        t->commit();
    say(opts, "wrote " + out + " (" + fmt_bytes(file_size) + ", " + std::to_string(grids.size()) +
                  " grid" + (grids.size() == 1 ? "" : "s") + ", " + quantize_name(opts.quantize) +
                  ")");
    if (opts.stats)
        print_stats(reports, file_size, out);
    return ExitOk;
}

int convert_file(const std::string &in, const std::string &out, const Options &opts) {
    // Fail on an unwritable output before reading a large input
    { TempFile probe(out); }
    return convert_grids(read_input(in), dq(in), out, opts);
}

int verify_only(const std::string &in, const std::string &nvdb, const Options &opts) {
    openvdb::GridPtrVec all = read_input(in);
    std::vector<Prepared> grids = select_and_prepare(all, dq(in), opts);
    std::vector<nanovdb::io::GridMetaData> meta;
    try {
        meta = nanovdb::io::readGridMetaData(nvdb);
    } catch (const std::exception &e) {
        throw Error(dq(nvdb) + ": cannot read as a NanoVDB file: " + e.what(), ExitVerify);
    }
    if (meta.size() != grids.size())
        throw Error(dq(nvdb) + " holds " + std::to_string(meta.size()) + " grid(s), but " +
                        std::to_string(grids.size()) + " would be converted from " + dq(in),
                    ExitVerify);
    Options o = opts;
    if (o.verify == 0)
        o.verify = 100000;
    bool ok = true;
    for (size_t i = 0; i < grids.size(); ++i) {
        Handle h;
        try {
            h = nanovdb::io::readGrid<nanovdb::HostBuffer>(nvdb, uint64_t(i));
        } catch (const std::exception &e) {
            throw Error(dq(nvdb) + ": cannot read grid " + std::to_string(i) + ": " + e.what(),
                        ExitVerify);
        }
        if (grids[i].vec) {
            const auto *nano = h.grid<nanovdb::Vec3f>();
            ok = nano && verify_vec3(*grids[i].vec, *nano, grids[i].name, o) && ok;
            continue;
        }
        ok = verify_float(*grids[i].grid, h, grids[i].name, o) && ok;
        if (!opts.probes.empty())
            print_probes(*grids[i].grid, h, grids[i].name, opts);
    }
    if (!ok) {
        std::fflush(stdout);
        std::fprintf(stderr, "vdb2nvdb: error: %s does not match %s\n", nvdb.c_str(), in.c_str());
        return ExitVerify;
    }
    say(opts, nvdb + " matches " + in);
    return ExitOk;
}

} // namespace vdb2nvdb
