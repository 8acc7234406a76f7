"""The simulator's random streams: one generator per (seed, role, source), independent of every
other by SeedSequence hashing, so the same spec and seed give the same episode bit for bit whatever
simulates it and however many episodes are simulated together."""

from __future__ import annotations

import itertools
from typing import Iterator, Sequence

import numpy as np

from deint_env.errors import DeintError

# The random streams' roles (the second word of their seed key).
DRAW, MISSING, JITTER, SPURIOUS, AMPLITUDE_NOISE, PRIORS, MODULATION, CUMULATIVE, AMPLITUDE, WAVEFORM = range(10)
# Pulse descriptors draw from streams of their own, so a scenario's TOAs do not move when its sources
# gain descriptors (only pulses below the receiver's threshold go): per episode, and per pulse.
DESCRIPTOR_DRAW, DESCRIPTOR_PULSE = 10, 11


def stream(seed: int, role: int, index: int = 0) -> np.random.Generator:
    """The generator of one role (and source): independent of every other by SeedSequence hashing."""
    return np.random.default_rng([seed, role, index])


# Seeding a batch: numpy's SeedSequence (O'Neill's seed_seq hash) and PCG64 seeding, vectorised.
# Why not numpy's own API: it defines these streams (`stream` is the reference, and
# tests/test_simulate.py checks `streams` against it), but it seeds one stream at a time, and
# SeedSequence's hashing alone costs ~17 us a stream on the project machine against ~5 us for the whole
# batched path here; 100-pulse episodes of five sources simulated 5000 at a time (the vector env's
# autoresets) took 1.4-1.5x as long with `default_rng` (149 vs 100 us an episode, measured side by
# side).  numpy documents both algorithms as stable, so the copy cannot drift.
_SEED_BATCH = 32  # from this many streams on, seeding them together beats numpy's ~7 us per stream
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R, _MASK32 = np.uint32(0xCA01F9DD), np.uint32(0x4973F715), 0xFFFFFFFF
_PCG_MULT, _MASK128 = 0x2360ED051FC65DA44385DF649FCCF645, 2**128 - 1


def streams(seeds: Sequence[int], role: int, index: int = 0) -> Iterator[np.random.Generator]:
    """`stream(seed, role, index)` for each seed in turn, each to be used up before the next is asked
    for.  A batch's generator states are computed together (numpy's SeedSequence hashing and PCG64
    seeding, which numpy keeps stable, in vectorised arithmetic; tests compare them with `stream`)
    and loaded into one reused generator: ~1 us a stream instead of ~7."""
    if len(seeds) < _SEED_BATCH:
        yield from (stream(seed, role, index) for seed in seeds)
        return
    bit_generator = np.random.PCG64()
    rng = np.random.Generator(bit_generator)
    for state, inc in _pcg64_states(seeds, role, index):
        bit_generator.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc},
                               "has_uint32": 0, "uinteger": 0}
        yield rng


def _pcg64_states(seeds: Sequence[int], role: int, index: int) -> list[tuple[int, int]]:
    """The PCG64 (state, inc) that `np.random.default_rng([seed, role, index])` starts from."""
    seed = np.array(seeds, np.uint64)
    lo, hi = (seed & np.uint64(_MASK32)).astype(np.uint32), (seed >> np.uint64(32)).astype(np.uint32)
    two = hi > 0  # a seed >= 2^32 takes two entropy words, lowest first
    entropy = [lo, np.where(two, hi, np.uint32(role)), np.where(two, np.uint32(role), np.uint32(index)),
               np.where(two, np.uint32(index), np.uint32(0))]  # short entropy is hashed as if 0-padded
    hash_const = _INIT_A

    def hashmix(value):
        nonlocal hash_const
        value = value ^ np.uint32(hash_const)
        hash_const = hash_const * _MULT_A & _MASK32
        value = value * np.uint32(hash_const)
        return value ^ (value >> np.uint32(16))

    pool = [hashmix(word) for word in entropy]
    for i_src in range(4):
        for i_dst in range(4):
            if i_src != i_dst:
                mixed = _MIX_L * pool[i_dst] - _MIX_R * hashmix(pool[i_src])
                pool[i_dst] = mixed ^ (mixed >> np.uint32(16))
    hash_const = _INIT_B
    words = []  # generate_state(4, np.uint64): 8 words, little-endian pairs
    for i in range(8):
        value = pool[i % 4] ^ np.uint32(hash_const)
        hash_const = hash_const * _MULT_B & _MASK32
        value = value * np.uint32(hash_const)
        words.append((value ^ (value >> np.uint32(16))).astype(np.uint64))
    w = [(words[2 * j] | (words[2 * j + 1] << np.uint64(32))).tolist() for j in range(4)]
    states = []
    for w0, w1, w2, w3 in zip(*w):  # pcg_setseq_128_srandom_r(initstate, initseq)
        inc = ((w2 << 64 | w3) << 1 | 1) & _MASK128
        states.append((((inc + (w0 << 64 | w1)) * _PCG_MULT + inc) & _MASK128, inc))
    return states


def check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise DeintError(f"seed={seed!r} is invalid: an integer in [0, 2^63)")
    return int(seed)


def fill(blocks: list[np.ndarray], seeds: list[int], role: int, index: int = 0, counts: np.ndarray | None = None,
          normal: bool = True) -> None:
    """Deal each episode's standard normals (or uniforms in [0, 1)) from its own stream (seed, role,
    index) to row j of each block in turn, `counts[j, b]` entries of block b (default: whole rows).

    A draw of size a then one of size b continue the stream exactly as one draw of size a + b, so
    the rows hold exactly what the lone episode draws in one call."""
    per_row = itertools.repeat([block.shape[1] for block in blocks]) if counts is None else counts.tolist()
    for j, (rng, row_counts) in enumerate(zip(streams(seeds, role, index), per_row)):
        draw = rng.standard_normal if normal else rng.random
        for block, c in zip(blocks, row_counts):
            draw(out=block[j, :c])
