// A blackbody's CIE XYZ in Mitsuba's units, for the Python package
// (nanovdb_mitsuba/fire.py picks a fire's brightness with it): the integral
// the emissive medium tabulates (nanovdb_mitsuba/blackbody.h's xyz()),
// exported with C linkage from the emissiveheterogeneous plugin, so that
// Planck x CIE is written once.
#include <nanovdb_mitsuba/blackbody.h>

extern "C" MI_EXPORT void nvdb_blackbody_xyz(double kelvin, double *out) {
    mitsuba::Color<double, 3> c(0.0);
    if (kelvin > 0.0)
        c = mitsuba::blackbody::xyz(kelvin);
    for (int k = 0; k < 3; ++k)
        out[k] = c[k];
}
