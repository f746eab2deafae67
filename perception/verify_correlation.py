"""Raw texture scores of block crops: band-passed normalised cross-correlation.

The kernels of :mod:`perception.verify` (which scales these raw scores by a cohort and
decides).

Score of a query block ``q`` against an enrolled block ``e``: both grey, ``e`` resized to
``q``'s size (``q`` shrunk to ``e``'s area first if it is larger: :func:`work_size`), times
each of :data:`SCALES` (the detector's boxes differ by a few per cent),
both band-passed (difference of Gaussians, :data:`BAND_SIGMAS` pixels: the grain, not
the light), then the largest normalised cross-correlation (``cv2.matchTemplate``,
``TM_CCOEFF_NORMED``) of ``q`` without a border of :data:`BORDER` (the block's edges
look alike on every pallet) over every shift and scale, leaving out what on the query is
not the block's own face: dark blots (new stains, ink and burnt marks: :data:`DARK_MADS`)
and anything far from the face's colour (a strap, film, a label: :data:`COLOUR_OFF`).

Band-passed enrolled crops are kept per size (:data:`BAND_CACHE_BYTES`, keyed by their
pixels); with a mask, a template is correlated with every enrolled crop of one size at once
(:func:`_masked_best`); a query's jobs (blocks, work sizes, scales) are shared by
:data:`THREADS` threads (:func:`_scores`). The figures depend on neither the cache nor the
thread that computes them.
"""

from __future__ import annotations

import functools
import hashlib
import os
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import cv2
import numpy as np

#: how much of each side of the query crop is left out of the template (fraction)
BORDER = 0.08
#: scales of the enrolled crop relative to the query crop that are tried
SCALES = (0.92, 1.0, 1.08)
#: difference-of-Gaussians band (pixels at the query crop's size)
BAND_SIGMAS = (0.7, 3.0)
#: a query pixel this many robust deviations darker than its surroundings is a blot
#: (stain, ink, burn) and is left out of the correlation
DARK_MADS = 2.5
#: a query pixel farther from the face's median colour (Lab) than this many times the
#: median pixel's distance, and at least MIN_COLOUR_OFF, is not the face (a strap, film, a
#: label, a load). The face's own grain and marks stay within about twice the median; a
#: wider bar (4.4 times, until issue 17's second pass) let every strap of the bench
#: through unmasked, and the one block it crossed dragged the whole side's score down
COLOUR_OFF = 2.0
MIN_COLOUR_OFF = 18.0
#: ... unless fewer than this share of the template would be left
MIN_KEPT = 0.4


def grey(crop: np.ndarray) -> np.ndarray:
    """A BGR (or already grey) crop as a float32 grey image (grey float32 is returned as is)."""
    img = np.asarray(crop)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img if img.dtype == np.float32 else img.astype(np.float32)


def _dog(g: np.ndarray) -> np.ndarray:
    """The grey image band-passed (difference of Gaussians, :data:`BAND_SIGMAS`)."""
    lo, hi = BAND_SIGMAS
    return cv2.GaussianBlur(g, (0, 0), lo) - cv2.GaussianBlur(g, (0, 0), hi)


def _band(g: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    return _dog(cv2.resize(g, (hw[1], hw[0]), interpolation=cv2.INTER_AREA))


def _template(
    query: np.ndarray, hw: tuple[int, int], colour: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The band-passed grey query at size ``hw`` without its border, and the mask of what
    is the block's own face (None if all of it is): dark blots (stains, ink, burnt marks)
    and, with the BGR ``colour`` crop, whatever is far from the face's own colour (a
    strap, film, a label, a load hanging over it) are left out."""
    h, w = hw
    g = cv2.resize(query, (w, h), interpolation=cv2.INTER_AREA)
    b = _dog(g)
    r = cv2.GaussianBlur(g, (0, 0), 1.0) - cv2.GaussianBlur(g, (0, 0), max(h, w) / 6.0)
    off = r < -DARK_MADS * _mad(r)
    if colour is not None and colour.ndim == 3:
        lab = cv2.cvtColor(
            cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2LAB
        )
        lab = cv2.GaussianBlur(lab.astype(np.float32), (0, 0), 1.0)
        dist = np.linalg.norm(lab - np.median(lab.reshape(-1, 3), axis=0), axis=2)
        off |= dist > max(COLOUR_OFF * float(np.median(dist)), MIN_COLOUR_OFF)
    off = cv2.dilate(off.astype(np.uint8), np.ones((3, 3), np.uint8))
    mh, mw = max(1, int(BORDER * h)), max(1, int(BORDER * w))
    keep = (1 - off[mh : h - mh, mw : w - mw]).astype(np.float32)
    mask = None if keep.all() or keep.mean() < MIN_KEPT else keep
    return b[mh : h - mh, mw : w - mw], mask


def _mad(x: np.ndarray) -> float:
    """Robust standard deviation of ``x`` (1.4826 times the median absolute deviation)."""
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) + 1e-3


def work_size(query_hw: tuple[int, int], enrolled_hw: tuple[int, int]) -> tuple[int, int]:
    """Where a query block is compared with an enrolled one: at the query's size, or
    shrunk to the enrolled crop's area when the query is larger (an enrolled crop blown up
    has no fine grain left, only the marks every pallet shares)."""
    qh, qw = query_hw
    f = min(1.0, float(np.sqrt(enrolled_hw[0] * enrolled_hw[1] / max(1, qh * qw))))
    return max(1, int(round(qh * f))), max(1, int(round(qw * f)))


def block_score(
    template: np.ndarray,
    work_hw: tuple[int, int],
    enrolled: np.ndarray,
    mask: np.ndarray | None = None,
) -> float:
    """Largest normalised cross-correlation of a query block's template (band-passed at
    ``work_hw``, without its border; ``mask`` 0 where it is not counted) over the enrolled
    grey crop resized to ``work_hw`` times each of :data:`SCALES`."""
    return float(block_scores(template, work_hw, [enrolled], mask)[0])


#: band-passed enrolled crops per size kept at most (bytes): the cohort and the gallery's
#: sides are compared with every query, and query blocks come in few sizes
BAND_CACHE_BYTES = 192 << 20
_band_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()
_band_cache_bytes = 0
_band_lock = threading.Lock()


_key_memo: dict[int, tuple[weakref.ref, tuple]] = {}


def _crop_key(g: np.ndarray) -> tuple:
    """A key of a grey crop's content (its shape and a 128-bit digest of its pixels);
    remembered for a read-only array (the shipped cohort's, the gallery's) while it lives."""
    memo = None if g.flags.writeable else _key_memo.get(id(g))
    if memo is not None and memo[0]() is g:
        return memo[1]
    c = np.ascontiguousarray(g)
    key = (c.shape, c.dtype.str, hashlib.blake2b(c, digest_size=16).digest())
    if not g.flags.writeable:
        gid = id(g)
        with _band_lock:
            _key_memo[gid] = (weakref.ref(g, lambda _, gid=gid: _key_memo.pop(gid, None)), key)
    return key


def _cached_band(g: np.ndarray, key: tuple, hw: tuple[int, int]) -> np.ndarray:
    """:func:`_band` of the grey crop ``g`` (content ``key``) at ``hw``, computed once while
    it stays among the recently used (a pure function of the pixels and the size)."""
    global _band_cache_bytes
    k = (key, hw)
    with _band_lock:
        hit = _band_cache.get(k)
        if hit is not None:
            _band_cache.move_to_end(k)
            return hit
    band = _band(g, hw)
    band.flags.writeable = False
    with _band_lock:
        if k not in _band_cache:
            _band_cache[k] = band
            _band_cache_bytes += band.nbytes
            while _band_cache_bytes > BAND_CACHE_BYTES and len(_band_cache) > 1:
                _, old = _band_cache.popitem(last=False)
                _band_cache_bytes -= old.nbytes
    return band


def clear_band_cache() -> None:
    """Forget every band-passed crop kept by :func:`block_scores` (tests, benches)."""
    global _band_cache_bytes
    with _band_lock:
        _band_cache.clear()
        _band_cache_bytes = 0


#: multiply-adds per complex matrix product kept below OpenBLAS's threading threshold
_GEMM_ONE_THREAD = 48_000


@functools.lru_cache(maxsize=256)
def _fft_len(n: int) -> int:
    """The smallest length >= ``n`` with no prime factor above 5 (a fast FFT length)."""
    while True:
        m = n
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return n
        n += 1


def _masked_best(bands: Sequence[np.ndarray], template: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per tile of ``bands`` (n images of one size eh x ew), the largest finite
    ``TM_CCOEFF_NORMED`` of ``template`` (th, tw) with the 0/1 ``mask`` over every shift
    inside the tile: OpenCV's masked formula,
    ``corr(I, T') / (|T'| sqrt(corr(I^2, M) - corr(I, M)^2 / sum(M)))`` with
    ``T' = M (T - mean_M(T))``, for all tiles at once in float64 (OpenCV's own figures
    differ from these by its float32 rounding, about 1e-7).

    Along x each correlation is a product of row spectra (a valid shift never wraps round
    the tile); along y, a sum over the template's rows: one small matrix product per
    frequency. -inf for a tile without a finite figure."""
    n = len(bands)
    eh, ew = bands[0].shape
    th, tw = template.shape
    rh, rw = eh - th + 1, ew - tw + 1
    m = mask.astype(np.float64)
    t = template.astype(np.float64)
    msum = float(m.sum())
    tp = (t - float((t * m).sum()) / msum) * m
    tnorm = float(np.sqrt((tp * tp).sum()))
    nfft = _fft_len(ew)
    # the tiles and their squares, columns first: (2, ew, eh, n); their row spectra come
    # out frequency first, (2, wf, eh, n), as the products below take them
    img = np.empty((2, ew, eh, n))
    np.stack(bands, axis=2, out=img[0].transpose(1, 0, 2), casting="same_kind")
    np.multiply(img[0], img[0], out=img[1])
    spec = np.fft.rfft(img, n=nfft, axis=1)
    k = np.conj(np.fft.rfft(np.stack([tp, m]), n=nfft, axis=2)).transpose(2, 0, 1)  # wf, 2, th
    wf = k.shape[0]
    rows = np.zeros((wf, 2, rh, eh), np.complex128)  # per frequency: sum over template rows
    for y in range(rh):
        rows[:, :, y, y : y + th] = k
    # corr(I, T') and corr(I, M) from the tiles, corr(I^2, M) from their squares; in
    # slices of tiles small enough for OpenBLAS to stay on one thread (above about 64k
    # multiply-adds a product it threads, and on a busy host its threads spin for far
    # longer than the product takes)
    both, mrows = rows.reshape(wf, 2 * rh, eh), rows[:, 1]
    c = np.empty((wf, 3 * rh, n), np.complex128)
    step = max(1, _GEMM_ONE_THREAD // (2 * rh * eh))
    for i in range(0, n, step):
        np.matmul(both, spec[0, :, :, i : i + step], out=c[:, : 2 * rh, i : i + step])
        np.matmul(mrows, spec[1, :, :, i : i + step], out=c[:, 2 * rh :, i : i + step])
    r = np.fft.irfft(c, n=nfft, axis=0)[:rw]  # rw, 3 rh, n
    c1, c2, c3 = r[:, :rh], r[:, rh : 2 * rh], r[:, 2 * rh :]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        r = c1 / (np.sqrt(c3 - c2 * c2 / msum) * tnorm)
    return np.where(np.isfinite(r), r, -np.inf).reshape(rw * rh, n).max(axis=0)


def _scale_scores(
    template: np.ndarray,
    work_hw: tuple[int, int],
    enrolled: Sequence[np.ndarray],
    mask: np.ndarray | None,
    keys: Sequence[tuple],
    scale: float,
) -> np.ndarray | None:
    """The best figure of each enrolled crop at one of :data:`SCALES` (-inf where none is
    finite), None if the template does not fit at that scale."""
    h, w = work_hw
    th, tw = template.shape[:2]
    eh, ew = int(round(h * scale)), int(round(w * scale))
    if eh < th or ew < tw:
        return None
    bands = [_cached_band(e, k, (eh, ew)) for e, k in zip(enrolled, keys, strict=True)]
    if mask is not None:
        return _masked_best(bands, template, mask)
    best = np.full(len(bands), -np.inf)  # OpenCV's unmasked figures, crop by crop
    for i, b in enumerate(bands):
        r = cv2.matchTemplate(b, template, cv2.TM_CCOEFF_NORMED)
        if r.size:
            m = float(r.max())
            best[i] = m if m > -np.inf else best[i]  # a NaN maximum counts for nothing
    return best


def _best_of(best: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    """``best`` raised to one scale's figures (as ``max(best, figure)`` one by one)."""
    if scale is None:
        return best
    return np.where(scale > best, scale, best)


def block_scores(
    template: np.ndarray,
    work_hw: tuple[int, int],
    enrolled: Sequence[np.ndarray],
    mask: np.ndarray | None = None,
    keys: Sequence[tuple] | None = None,
) -> np.ndarray:
    """:func:`block_score` of one query template against several enrolled grey crops.

    With a mask, every crop's band-passed image of one scale is correlated at once
    (:func:`_masked_best`: the figures of one ``cv2.matchTemplate`` per crop to about
    1e-7); without one, one ``cv2.matchTemplate`` per crop. Band-passed crops are kept per
    size (:data:`BAND_CACHE_BYTES`). ``keys``: the crops' :func:`_crop_key`, if known."""
    best = np.full(len(enrolled), -1.0)
    if not len(enrolled):
        return best
    if keys is None:
        keys = [_crop_key(e) for e in enrolled]
    for s in SCALES:
        best = _best_of(best, _scale_scores(template, work_hw, enrolled, mask, keys, s))
    return best


#: threads scoring a query (1 or 2): the blocks, work sizes and scales are scored on two
#: cores; the figures do not depend on which thread computes them
THREADS = 2
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _after_fork() -> None:
    """A forked child has neither the worker nor a lock another thread held: new ones."""
    global _pool, _pool_lock, _band_lock
    _pool, _pool_lock, _band_lock = None, threading.Lock(), threading.Lock()


os.register_at_fork(after_in_child=_after_fork)


def _two_threads(jobs: list[Callable[[], Any]]) -> list[Any]:
    """Run ``jobs`` on this thread and one worker (each job once, results in order)."""
    global _pool
    if len(jobs) < 2 or THREADS < 2 or (os.cpu_count() or 1) < 2:
        return [job() for job in jobs]
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="verify")
    results: list[Any] = [None] * len(jobs)
    taken = [False] * len(jobs)
    take = threading.Lock()

    def work() -> None:
        while True:
            with take:
                i = next((k for k, t in enumerate(taken) if not t), None)
                if i is None:
                    return
                taken[i] = True
            results[i] = jobs[i]()

    helper = _pool.submit(work)
    work()
    helper.result()
    return results


def _scores(
    queries: Sequence[np.ndarray],
    sides: Sequence[Sequence[np.ndarray]],
    colours: Sequence[np.ndarray | None] | None = None,
) -> np.ndarray:
    """Raw scores (len(sides), 3) of the three grey query blocks (``colours``: their BGR
    crops, for the mask) against every side's blocks (every block, work size and scale one
    job, on two threads)."""
    out = np.full((len(sides), len(queries)), np.nan)
    keys: dict[int, tuple] = {}  # id -> content key of the crops (alive during the call)
    greys: dict[int, np.ndarray] = {}
    groups: list[tuple[int, list[int], tuple[int, int], list[np.ndarray], list[tuple]]] = []
    for b, q in enumerate(queries):
        if min(q.shape[:2]) < 6:
            continue
        by_size: dict[tuple[int, int], list[int]] = {}
        crops: dict[int, np.ndarray] = {}
        for j, side in enumerate(sides):
            if b < len(side) and side[b] is not None:
                src = side[b]
                e = greys.get(id(src))
                if e is None:
                    e = greys[id(src)] = grey(src)
                    keys[id(src)] = _crop_key(e)
                crops[j] = e
                by_size.setdefault(work_size(q.shape[:2], e.shape[:2]), []).append(j)
        for hw, js in by_size.items():
            ks = [keys[id(sides[j][b])] for j in js]
            groups.append((b, js, hw, [crops[j] for j in js], ks))
    templates = _two_threads(
        [
            partial(_template, queries[b], hw, colours[b] if colours else None)
            for b, _, hw, _, _ in groups
        ]
    )
    jobs, owner = [], []
    for g, ((_, _, hw, es, ks), (t, mask)) in enumerate(zip(groups, templates, strict=True)):
        for s in SCALES:
            jobs.append(partial(_scale_scores, t, hw, es, mask, ks, s))
            owner.append(g)
    best = [np.full(len(g[1]), -1.0) for g in groups]
    for g, figures in zip(owner, _two_threads(jobs), strict=True):
        best[g] = _best_of(best[g], figures)
    for (b, js, _, _, _), figures in zip(groups, best, strict=True):
        out[js, b] = figures
    return out


__all__ = [
    "BAND_CACHE_BYTES",
    "BAND_SIGMAS",
    "BORDER",
    "COLOUR_OFF",
    "DARK_MADS",
    "MIN_COLOUR_OFF",
    "MIN_KEPT",
    "SCALES",
    "THREADS",
    "block_score",
    "block_scores",
    "clear_band_cache",
    "grey",
    "work_size",
]
