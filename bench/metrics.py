"""Image error metrics (numpy only) and the equal-time comparison."""
import math

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])


def rmse(img, ref, ref_var_of_mean=None):
    """RMSE over all sensors, pixels and channels. With the reference's own
    noise estimate (variance of its mean, per pixel), that noise is
    subtracted from the MSE: E|x - r|^2 = |bias|^2 + var(x) + var(r)."""
    d = img.astype(np.float64) - ref.astype(np.float64)
    mse = float(np.mean(d * d))
    raw = math.sqrt(mse)
    if ref_var_of_mean is None:
        return raw, raw
    corr = mse - float(np.mean(ref_var_of_mean))
    return raw, math.sqrt(max(corr, 0.0))


def _gaussian_kernel(sigma=1.5, radius=5):
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def _filter2(a, k):
    """Separable 'valid' convolution of a 2D array with the 1D kernel k."""
    n = len(k)
    h, w = a.shape
    if h < n or w < n:  # tiny images: fall back to a window as large as they are
        return np.full((1, 1), a.mean())
    tmp = sum(k[i] * a[:, i:w - n + 1 + i] for i in range(n))
    return sum(k[i] * tmp[i:h - n + 1 + i, :] for i in range(n))


def ssim(img, ref):
    """Mean SSIM (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5,
    K1 = 0.01, K2 = 0.03) of the luminance, per sensor, averaged over the
    sensors. The data range L is the reference's maximum luminance per
    sensor (the images are HDR)."""
    vals = []
    for s in range(img.shape[0]):
        x = img[s].astype(np.float64) @ LUMA
        y = ref[s].astype(np.float64) @ LUMA
        L = max(float(y.max()), 1e-8)
        c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2
        k = _gaussian_kernel()
        mx, my = _filter2(x, k), _filter2(y, k)
        sxx = _filter2(x * x, k) - mx * mx
        syy = _filter2(y * y, k) - my * my
        sxy = _filter2(x * y, k) - mx * my
        m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        vals.append(float(m.mean()))
    return float(np.mean(vals))


def error_at_equal_time(a, b):
    """a, b: lists of (seconds, error) of two methods. Returns a dict:
    t (the longest time both reach), ea, eb (errors interpolated in log-log at t) and
    ratio = ea / eb; plus the Monte Carlo efficiency ratio
    (error^2 * time)_a / (error^2 * time)_b, i.e. how much longer a needs
    than b to reach the same error (median over the sweep points)."""
    a = sorted((t, e) for t, e in a if t > 0 and e > 0)
    b = sorted((t, e) for t, e in b if t > 0 and e > 0)
    res = {"t": None, "ea": None, "eb": None, "ratio": None, "cost_ratio": None}
    if not a or not b:
        return res
    ca = float(np.median([e * e * t for t, e in a]))
    cb = float(np.median([e * e * t for t, e in b]))
    res["cost_ratio"] = ca / cb
    lo = max(a[0][0], b[0][0])
    hi = min(a[-1][0], b[-1][0])

    def interp(pts, t):
        lt = np.log([p[0] for p in pts])
        le = np.log([p[1] for p in pts])
        return float(np.exp(np.interp(math.log(t), lt, le)))

    if lo <= hi:
        # The longest time both sweeps reach: there the renders are furthest
        # from the fixed per-render overhead that dominates the lowest spp.
        t = hi
        res.update(t=t, ea=interp(a, t), eb=interp(b, t))
    else:  # no overlap: extrapolate with error ~ t^-1/2 from the efficiency
        t = math.sqrt(a[-1][0] * b[0][0]) if a[-1][0] < b[0][0] else math.sqrt(b[-1][0] * a[0][0])
        res.update(t=t, ea=math.sqrt(ca / t), eb=math.sqrt(cb / t))
    res["ratio"] = res["ea"] / res["eb"]
    return res


def region_errors(img, ref, ref_var_of_mean, regions):
    """The error by region. regions: {name: boolean mask [S, H, W]} over
    the images' pixels (every channel counts). Returns {name: {"pixels",
    "rel_rmse" (the region's noise-corrected RMSE / the reference's mean
    there), "share" (the region's part of the image's summed squared
    error, noise-corrected)}}"""
    d = img.astype(np.float64) - ref.astype(np.float64)
    sq = d * d - ref_var_of_mean.astype(np.float64)
    total = float(sq.sum())
    out = {}
    for name, m in regions.items():
        n = int(m.sum())
        if n == 0:
            out[name] = {"pixels": 0, "rel_rmse": None, "share": None}
            continue
        s = float(sq[m].sum())
        level = float(ref[m].mean())
        out[name] = {"pixels": n,
                     "rel_rmse": math.sqrt(max(s / (n * ref.shape[-1]), 0.0)) / level
                     if level > 0 else None,
                     "share": s / total if total > 0 else None}
    return out
