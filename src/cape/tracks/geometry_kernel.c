/* The projection of a point onto a closed polyline (cape.tracks.geometry.ClosedPath.project),
 * as compiled C: the same candidate window, the same arithmetic in the same order, the same
 * tie rule, so the same bits as the NumPy path (a test holds the two equal). It runs four times
 * a step in every closed-loop run, where NumPy's per-call cost on ~100 candidates was most of
 * the loop around the controller and the plant.
 *
 * Compiled with -ffp-contract=off: no fused multiply-add, which would round differently.
 */
#include <math.h>

/* NumPy's float remainder (npy_divmod), which is also Python's float %. */
static double remainder_of(double a, double b) {
    double mod = fmod(a, b);
    if (!b) {
        return mod;
    }
    if (mod) {
        if ((b < 0) != (mod < 0)) {
            mod += b;
        }
    } else {
        mod = copysign(0.0, b);
    }
    return mod;
}

/* numpy.searchsorted(a, v, side="right"): the count of elements <= v. */
static long search_right(const double *a, long n, double v) {
    long lo = 0, hi = n;
    while (lo < hi) {
        long mid = lo + (hi - lo) / 2;
        if (v < a[mid]) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    return lo;
}

/* numpy.searchsorted(a, v, side="left"): the count of elements < v. */
static long search_left(const double *a, long n, double v) {
    long lo = 0, hi = n;
    while (lo < hi) {
        long mid = lo + (hi - lo) / 2;
        if (a[mid] < v) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    return lo;
}

/* NumPy's clip of one float64 (_NPY_CLIP: max, then min, NaN kept). */
static double clip01(double t) {
    if (!isnan(t)) {
        t = t > 0.0 ? t : 0.0;
    }
    if (!isnan(t)) {
        t = t < 1.0 ? t : 1.0;
    }
    return t;
}

typedef struct {
    long best;
    int nan_seen;
    double best_dist, t, qx, qy;
} Nearest;

static void consider(const double *seg, long n, long i, double px, double py, Nearest *near) {
    const double ax = seg[i], ay = seg[n + i], dx = seg[2 * n + i], dy = seg[3 * n + i];
    const double len2 = seg[4 * n + i], bx = seg[5 * n + i], by = seg[6 * n + i];
    const double t = clip01(((px - ax) * dx + (py - ay) * dy) / len2);
    const double qx = t <= 0.0 ? ax : (t >= 1.0 ? bx : ax + t * dx);
    const double qy = t <= 0.0 ? ay : (t >= 1.0 ? by : ay + t * dy);
    const double dist = hypot(px - qx, py - qy);
    /* numpy.argmin: the first minimum, or the first NaN if there is one */
    if (near->nan_seen) {
        return;
    }
    if (isnan(dist) || near->best < 0 || dist < near->best_dist) {
        near->best = i;
        near->nan_seen = isnan(dist);
        near->best_dist = dist;
        near->t = t;
        near->qx = qx;
        near->qy = qy;
    }
}

/* seg: the path's (8, n) segment table, row-major (start x, y, direction x, y, squared length,
 * end x, y, length); s_points: each segment's start arc length; use_window: 0 searches every
 * segment. Writes s, offset, x, y to out; returns the segment's index. */
long cape_project(const double *seg, const double *s_points, long n, double length, double px,
                  double py, int use_window, double s_hint, double window, double *out) {
    Nearest near = {-1, 0, 0.0, 0.0, 0.0, 0.0};
    const double *seg_len = seg + 7 * n;
    if (!use_window || 2 * window >= length) {
        for (long i = 0; i < n; i++) {
            consider(seg, n, i, px, py, &near);
        }
    } else {
        const double low = s_hint - window;
        const double start = remainder_of(low, length);
        const long first = search_right(s_points, n, start) - 2;
        const double end = start + 2 * window;
        const long last = end <= length ? search_left(s_points, n, end) + 1
                                        : n + search_left(s_points, n, end - length) + 1;
        long a_end, b_start; /* the candidates: [0, a_end) and [b_start, n), or one range */
        if (first < 0 || last > n) {
            a_end = last > n ? last - n : last;
            b_start = first < 0 ? first + n : first;
        } else {
            a_end = 0;
            b_start = first;
        }
        const long stop = (first < 0 || last > n) ? n : last;
        for (long i = 0; i < stop; i++) {
            if (i >= a_end && i < b_start) {
                continue;
            }
            const double rel_start = remainder_of(s_points[i] - low, length);
            if (rel_start <= 2 * window || rel_start + seg_len[i] >= length) {
                consider(seg, n, i, px, py, &near);
            }
        }
    }
    const long i = near.best;
    const double ax = seg[i], ay = seg[n + i], dx = seg[2 * n + i], dy = seg[3 * n + i];
    const double cross = dx * (py - ay) - dy * (px - ax);
    const double side = cross >= 0 ? 1.0 : -1.0;
    out[0] = remainder_of(s_points[i] + near.t * seg_len[i], length);
    out[1] = side * near.best_dist;
    out[2] = near.qx;
    out[3] = near.qy;
    return i;
}
