// vdb2nvdb's messages. See format.h.

#include <nanovdb_convert/format.h>

#include <cstdio>

namespace vdb2nvdb {

std::string dq(const std::string &s) { return "\"" + s + "\""; }

std::string fmt_count(uint64_t n) {
    std::string s = std::to_string(n), out;
    for (size_t i = 0; i < s.size(); ++i) {
        if (i > 0 && (s.size() - i) % 3 == 0)
            out += ',';
        out += s[i];
    }
    return out;
}

std::string fmt_bytes(uint64_t n) {
    char buf[64];
    if (n >= (uint64_t(1) << 30))
        std::snprintf(buf, sizeof(buf), " (%.2f GiB)", double(n) / double(1u << 30));
    else if (n >= (uint64_t(1) << 20))
        std::snprintf(buf, sizeof(buf), " (%.1f MiB)", double(n) / double(1u << 20));
    else if (n >= 1024)
        std::snprintf(buf, sizeof(buf), " (%.1f KiB)", double(n) / 1024.0);
    else
        buf[0] = '\0';
    return fmt_count(n) + " B" + buf;
}

std::string fmt_coord(const openvdb::Coord &c) {
    return "(" + std::to_string(c.x()) + ", " + std::to_string(c.y()) + ", " +
           std::to_string(c.z()) + ")";
}

std::string fmt_float(double v) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.9g", v);
    return buf;
}

std::string class_name(openvdb::GridClass c) {
    return openvdb::GridBase::gridClassToString(c);
}

std::string grid_summary(const openvdb::GridBase &g) {
    return dq(g.getName()) + " (" + g.valueType() + ", " + class_name(g.getGridClass()) + ")";
}

std::string list_grids(const openvdb::GridPtrVec &grids) {
    std::string s;
    for (const auto &g : grids)
        s += (s.empty() ? "" : ", ") + grid_summary(*g);
    return s.empty() ? "(no grids)" : s;
}

void say(const Options &opts, const std::string &msg) {
    if (!opts.quiet)
        std::printf("%s\n", msg.c_str());
    std::fflush(stdout);
}

void note(const std::string &msg) {
    std::fflush(stdout);
    std::fprintf(stderr, "vdb2nvdb: note: %s\n", msg.c_str());
}

} // namespace vdb2nvdb
