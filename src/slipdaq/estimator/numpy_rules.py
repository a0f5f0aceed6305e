"""numpy's arithmetic where a kernel must give numpy's bits: np.interp (its search from the last point's index and its
formula, numpy's compiled_base.c) and np.sum's pairwise summation (loops_utils.h), written out step by step for
kernels (tests/estimator/test_numpy_rules.py holds them to numpy on random and awkward inputs)."""

from __future__ import annotations

import numpy as np

LIKELY_IN_CACHE_SIZE = 8
PW_BLOCKSIZE = 128


def search_with_guess(key: float, arr: np.ndarray, guess: int) -> int:
    """np.interp's search: -1 below arr[0], len(arr) above arr[-1], else i with arr[i] <= key < arr[i + 1] (the last
    index for key == arr[-1]), looked for first around guess (numpy's binary_search_with_guess)."""
    n = len(arr)
    imin = 0
    imax = n
    if key > arr[n - 1]:
        return n
    if key < arr[0]:
        return -1
    if n <= 4:
        i = 1
        while i < n and key >= arr[i]:
            i += 1
        return i - 1
    guess = min(guess, n - 3)
    guess = max(guess, 1)
    if key < arr[guess]:
        if key < arr[guess - 1]:
            imax = guess - 1
            if guess > LIKELY_IN_CACHE_SIZE and key >= arr[guess - LIKELY_IN_CACHE_SIZE]:
                imin = guess - LIKELY_IN_CACHE_SIZE
        else:
            return guess - 1
    else:
        if key < arr[guess + 1]:
            return guess
        if key < arr[guess + 2]:
            return guess + 1
        imin = guess + 2
        if guess < n - LIKELY_IN_CACHE_SIZE - 1 and key < arr[guess + LIKELY_IN_CACHE_SIZE]:
            imax = guess + LIKELY_IN_CACHE_SIZE
    while imin < imax:
        imid = imin + ((imax - imin) >> 1)
        if key >= arr[imid]:
            imin = imid + 1
        else:
            imax = imid
    return imin - 1


def interp_at(xv: float, xp: np.ndarray, fp: np.ndarray, guess: int) -> tuple[float, int]:
    """(np.interp(xv, xp, fp), the index its search found: the next point's guess), xp at least two points (left and
    right: fp's ends)."""
    n = len(xp)
    if xv != xv:
        return xv, guess
    j = search_with_guess(xv, xp, guess)
    if j == -1:
        return fp[0], j
    if j == n:
        return fp[n - 1], j
    if j == n - 1 or xp[j] == xv:
        return fp[j], j
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    y = slope * (xv - xp[j]) + fp[j]
    if y != y:  # nan one way: the other
        y = slope * (xv - xp[j + 1]) + fp[j + 1]
        if y != y and fp[j] == fp[j + 1]:
            y = fp[j]
    return y, j


def interp_into(x: np.ndarray, xp: np.ndarray, fp: np.ndarray, out: np.ndarray) -> None:
    """out[:] = np.interp(x, xp, fp) (left and right: fp's ends; xp at least one point)."""
    if len(xp) == 1:  # left, right and the point itself are all fp[0] (a NaN included)
        for i in range(len(x)):
            out[i] = fp[0]
        return
    j = 0
    for i in range(len(x)):
        out[i], j = interp_at(x[i], xp, fp, j)


def block_sum(a: np.ndarray, start: int, n: int) -> float:
    """numpy's pairwise_sum of a[start:start + n] for n <= PW_BLOCKSIZE: eight accumulators, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(start, start + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    while i < n - (n % 8):
        k = start + i
        r0 += a[k]
        r1 += a[k + 1]
        r2 += a[k + 2]
        r3 += a[k + 3]
        r4 += a[k + 4]
        r5 += a[k + 5]
        r6 += a[k + 6]
        r7 += a[k + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


def pairwise_sum(a: np.ndarray) -> float:
    """np.sum(a) of a float64 array, the same bits: 0.0 + numpy's pairwise sum, whose blocks of up to PW_BLOCKSIZE
    are halved at multiples of eight and added left + right (here on an explicit stack: kernels do not recurse)."""
    n = len(a)
    if n <= PW_BLOCKSIZE:
        return 0.0 + block_sum(a, 0, n)
    starts = np.zeros(64, dtype=np.int64)
    sizes = np.zeros(64, dtype=np.int64)
    stage = np.zeros(64, dtype=np.int64)  # 0: new, 1: its left half being summed, 2: its right half
    lefts = np.zeros(64)
    starts[0], sizes[0], stage[0] = 0, n, 0
    top = 1
    while True:
        k = top - 1
        size = sizes[k]
        if size > PW_BLOCKSIZE:  # a node: its left half next
            half = size // 2
            half -= half % 8
            stage[k] = 1
            starts[top], sizes[top], stage[top] = starts[k], half, 0
            top += 1
            continue
        total = block_sum(a, starts[k], size)
        top -= 1
        while top > 0:  # the sum up to the nodes it completes
            p = top - 1
            half = sizes[p] // 2
            half -= half % 8
            if stage[p] == 1:  # its left half: the right one next
                lefts[p] = total
                stage[p] = 2
                starts[top], sizes[top], stage[top] = starts[p] + half, sizes[p] - half, 0
                top += 1
                break
            total = lefts[p] + total
            top -= 1
        if top == 0:
            return 0.0 + total
