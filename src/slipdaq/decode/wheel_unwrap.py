"""Wheel signals -> cumulative revolutions, sample by sample in arrival order: the one rule for counts and speeds.

count: the counter's step since the wheel's last frame, modulo 2^bits and taken as the shorter way round (a step
backwards is rolling backwards); a step the wheel cannot have made in the time (forwards faster than MAX_REV_PER_S,
backwards faster than MAX_REVERSE_REV_PER_S, plus a tenth of a revolution) is a counter node reset: a new segment,
continued at the wheel's last rate and counted. A gap in the rolling sequence counter (Seq) is frames lost; a reset
frame starts a new Seq sequence.
speed: integrated over time by trapezoids into revolutions, not across a gap longer than MAX_INTEGRATION_GAP_S.
"""

from __future__ import annotations

import numpy as np

from slipdaq.compiled import kernel

MAX_REV_PER_S = 100.0
"""No road wheel turns faster (100 rev/s at r = 0.3 m is 680 km/h)."""
MAX_REVERSE_REV_PER_S = 5.0
"""Nor reverses faster (5 rev/s at r = 0.3 m is 34 km/h)."""
MAX_INTEGRATION_GAP_S = 1.0
"""A speed signal silent for longer than this is not integrated over the gap."""
MAX_COUNT_BITS = 62
"""Counters up to this width unwrap in int64 arithmetic."""

KIND_COUNT, KIND_SPEED = 0, 1
# columns of the per-wheel arrays
P_KIND, P_MODULUS, P_PULSES_PER_REV, P_SEQ_MODULUS = range(4)  # int64 parameters (SEQ_MODULUS 0: no Seq)
S_HAS_LAST, S_LAST_RAW, S_LAST_SEQ, S_COUNT = range(4)  # int64 state
F_SCALE, F_OFFSET, F_REV_PER_S_PER_UNIT = range(3)  # float64 parameters
T_LAST_T, T_LAST_RATE, T_REVOLUTIONS = range(3)  # float64 state
C_FRAMES, C_WRAPS, C_RESETS, C_LOST = range(4)  # int64 counters


def new_state(wheels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(int64 state, float64 state, counters) for that many wheels, before any frame."""
    return (np.zeros((wheels, 4), dtype=np.int64), np.zeros((wheels, 3), dtype=np.float64),
            np.zeros((wheels, 4), dtype=np.int64))


def _unwrap(wheel: np.ndarray, time_s: np.ndarray, raw_int: np.ndarray, raw_float: np.ndarray, seq: np.ndarray,
            params: np.ndarray, params_f: np.ndarray, state: np.ndarray, state_f: np.ndarray, counters: np.ndarray,
            count_out: np.ndarray, revolutions_out: np.ndarray, lost_out: np.ndarray, raw_out: np.ndarray) -> None:
    for k in range(len(wheel)):
        w = wheel[k]
        t = time_s[k]
        counters[w, C_FRAMES] += 1
        first = state[w, S_HAS_LAST] == 0
        if params[w, P_KIND] == KIND_SPEED:
            value = raw_float[k] * params_f[w, F_SCALE] + params_f[w, F_OFFSET]
            rate = value * params_f[w, F_REV_PER_S_PER_UNIT]
            if not first:
                dt = t - state_f[w, T_LAST_T]
                if 0.0 < dt <= MAX_INTEGRATION_GAP_S:
                    state_f[w, T_REVOLUTIONS] += 0.5 * (state_f[w, T_LAST_RATE] + rate) * dt
            state_f[w, T_LAST_RATE] = rate
            state_f[w, T_LAST_T] = t
            state[w, S_HAS_LAST] = 1
            count_out[k] = 0
            lost_out[k] = 0
            revolutions_out[k] = state_f[w, T_REVOLUTIONS]
            raw_out[k] = value
            continue
        raw = raw_int[k]
        ppr = params[w, P_PULSES_PER_REV]
        lost = 0
        if not first:
            modulus = params[w, P_MODULUS]
            last_raw = state[w, S_LAST_RAW]
            delta = (raw - last_raw) % modulus
            if delta >= modulus // 2:  # rolling backwards
                delta -= modulus
            dt = t - state_f[w, T_LAST_T]
            limit = MAX_REV_PER_S if delta >= 0 else MAX_REVERSE_REV_PER_S
            reset = abs(delta) > ppr * (limit * max(dt, 0.0) + 0.1)
            if reset:
                counters[w, C_RESETS] += 1  # a new segment: continue at the last rate
                delta = round(state_f[w, T_LAST_RATE] * max(dt, 0.0))
            else:
                if raw < last_raw and delta > 0:
                    counters[w, C_WRAPS] += 1
                if dt > 0:
                    state_f[w, T_LAST_RATE] = delta / dt
            state[w, S_COUNT] += delta
            seq_modulus = params[w, P_SEQ_MODULUS]
            if seq_modulus > 0 and not reset:
                lost = (seq[k] - state[w, S_LAST_SEQ] - 1) % seq_modulus
                counters[w, C_LOST] += lost
        state[w, S_LAST_RAW] = raw
        state[w, S_LAST_SEQ] = seq[k]
        state_f[w, T_LAST_T] = t
        state[w, S_HAS_LAST] = 1
        count_out[k] = state[w, S_COUNT]
        lost_out[k] = lost
        revolutions_out[k] = state[w, S_COUNT] / ppr
        raw_out[k] = raw


unwrap = kernel(_unwrap, "void(int64[:], float64[:], int64[:], float64[:], int64[:], int64[:, :], float64[:, :], "
                         "int64[:, :], float64[:, :], int64[:, :], int64[:], float64[:], int64[:], float64[:])")
"""unwrap()(...) writes the four outputs and updates state and counters in place."""
