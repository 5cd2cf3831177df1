// Choosing and preparing the grids to convert. See prepare.h.

#include <nanovdb_convert/prepare.h>

#include <openvdb/tools/LevelSetUtil.h>

#include <nanovdb_convert/error.h>
#include <nanovdb_convert/format.h>

namespace vdb2nvdb {

using openvdb::FloatGrid;

std::vector<Prepared> select_and_prepare(openvdb::GridPtrVec &all, const std::string &label,
                                         const Options &opts) {
    std::vector<bool> chosen(all.size(), false);
    if (!opts.grids.empty()) {
        for (const std::string &name : opts.grids) {
            bool found = false;
            for (size_t i = 0; i < all.size(); ++i) {
                if (all[i]->getName() != name)
                    continue;
                found = true;
                if (!all[i]->isType<FloatGrid>() && !all[i]->isType<openvdb::Vec3SGrid>())
                    throw Error(label + ": grid " + grid_summary(*all[i]) +
                                " cannot be converted: only float and vec3s grids are supported");
                chosen[i] = true;
            }
            if (!found)
                throw Error(label + ": no grid named " + dq(name) + "; the file holds: " +
                            list_grids(all));
        }
    } else {
        for (size_t i = 0; i < all.size(); ++i) {
            if (all[i]->isType<FloatGrid>() || all[i]->isType<openvdb::Vec3SGrid>())
                chosen[i] = true;
            else
                note("skipping grid " + grid_summary(*all[i]) +
                     ": only float and vec3s grids are converted");
        }
    }
    std::vector<Prepared> out;
    for (size_t i = 0; i < all.size(); ++i) {
        if (!chosen[i])
            continue;
        Prepared p;
        p.grid = openvdb::gridPtrCast<FloatGrid>(all[i]);
        p.vec = openvdb::gridPtrCast<openvdb::Vec3SGrid>(all[i]);
        p.name = p.base().getName();
        p.source_class = p.base().getGridClass();
        if (!p.base().transform().baseMap()->isLinear())
            throw Error(label + ": grid " + grid_summary(p.base()) + " has a non-affine (" +
                        p.base().transform().mapType() +
                        ") transform, which NanoVDB cannot represent");
        if (p.grid && p.source_class == openvdb::GRID_LEVEL_SET && !opts.keep_level_sets) {
            // Narrow band -> 0..1 ramp, interior 1 (active), exterior 0 (inactive)
            openvdb::tools::sdfToFogVolume(*p.grid);
            p.grid->setGridClass(openvdb::GRID_FOG_VOLUME);
            p.fogged = true;
        }
        out.push_back(std::move(p));
    }
    if (out.empty())
        throw Error(label + ": no float or vec3s grid to convert; the file holds: " + list_grids(all));
    return out;
}

} // namespace vdb2nvdb
