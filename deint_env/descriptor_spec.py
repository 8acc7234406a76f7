"""Pulse descriptor words in a scenario spec: an emitter's `DescriptorSpec` (centre frequency, pulse
width, angle of arrival, antenna scan) and the `ReceiverSpec` that hears them (staring or scanning),
as the Turing Synthetic Radar Dataset has them; simulated by deint_env/sim/descriptors.py.  Kept apart
from deint_env.scenario (which re-exports both) so that module stays one reading's length."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from deint_env.errors import check
from deint_env.spec_fields import Param, Range, _floats, _number, _param, _param_high, _param_low


SCANS = ("none", "circular", "sector")  # DescriptorSpec.scan
BEAMS = ("gaussian", "sinc2")  # main-lobe shapes of an emitter's or a scanning receiver's antenna
RECEIVER_MODES = ("staring", "scanning")  # ReceiverSpec.mode
MAX_DESCRIPTOR = 1e30  # the largest spread, hop or level: beyond, the drawn descriptors overflow to inf
MIN_SCAN_PERIOD = 1e-9  # an antenna turning faster has TOA / period overflow (the scenario's MIN_PERIOD)


def _check_beam(what: str, beamwidth: float, beam: str, sidelobe_db: float) -> None:
    """An antenna pattern: its main lobe's 3 dB width, shape and sidelobe floor."""
    check(0 < beamwidth <= 180, f"{what}.beamwidth", beamwidth, "the main lobe's 3 dB width in degrees, in (0, 180]")
    check(beam in BEAMS, f"{what}.beam", beam, f"one of {', '.join(BEAMS)}")
    check(-120 <= sidelobe_db < 0, f"{what}.sidelobe_db", sidelobe_db,
          "the sidelobe floor in dB below the main lobe's peak, in [-120, 0)")


def _levels_tuple(value: Any, what: str, positive: bool) -> tuple[float, ...]:
    v = _floats(value, what)
    check(len(v) != 1 and (not positive or all(x > 0 for x in v)) and all(abs(x) <= MAX_DESCRIPTOR for x in v),
          what, value, "empty (none) or at least two " + ("positive " if positive else "") +
          f"numbers of magnitude at most {MAX_DESCRIPTOR:g}")
    return v


@dataclass(frozen=True)
class DescriptorSpec:
    """An emitter's pulse descriptor words beside its TOAs (units: frequency MHz, pulse width us,
    angles degrees, times in the scenario's TOA unit -- us in the TSRD's convention).

    frequency: centre frequency (number or Range drawn per episode); frequency_std: its pulse-to-pulse
    jitter; frequency_hops: offsets from the centre, one drawn uniformly per pulse (empty: no hopping).
    pulse_width (number or Range); pulse_width_levels: multipliers of it, one drawn uniformly per
    pulse (empty: a fixed width).  aoa: angle of arrival (number or Range; None: uniform in [0, 360));
    aoa_rate: its drift in degrees per TOA unit (number or Range, e.g. Range(-r, r)).
    scan: the emitter's antenna.  "none": its main beam stays on the receiver (gain 1); "circular": it
    turns once per `scan_period`, so the receiver hears a burst as the main beam sweeps past and the
    sidelobes between; "sector": it sweeps a `sector` degrees wide back and forth (one period out and
    back), the receiver's bearing somewhere inside it (drawn per episode).  beamwidth: the main lobe's
    3 dB width; beam: its shape (gaussian, or sinc^2 with its own sidelobes); sidelobe_db: the floor of
    the pattern.  The received amplitude is the source's `amplitude` (its ERP less range loss) times
    the beam gain (times a scanning receiver's own, see ReceiverSpec).
    """

    frequency: Param = 10_000.0
    frequency_std: float = 0.0
    frequency_hops: tuple[float, ...] = ()
    pulse_width: Param = 1.0
    pulse_width_levels: tuple[float, ...] = ()
    aoa: Param | None = None
    aoa_rate: Param = 0.0
    scan: str = "none"
    scan_period: Param = 0.0
    sector: float = 0.0
    beamwidth: float = 3.0
    beam: str = "gaussian"
    sidelobe_db: float = -30.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "frequency", _param(self.frequency, "descriptors.frequency", positive=True))
        set_(self, "frequency_std", _number(self.frequency_std, "descriptors.frequency_std", 0.0, MAX_DESCRIPTOR))
        set_(self, "frequency_hops", _levels_tuple(self.frequency_hops, "descriptors.frequency_hops", False))
        check(self.frequency_span()[0] > 0, "descriptors.frequency_hops", list(self.frequency_hops),
              f"offsets that keep every frequency positive (the lowest centre is {_param_low(self.frequency):g})")
        set_(self, "pulse_width", _param(self.pulse_width, "descriptors.pulse_width", positive=True))
        set_(self, "pulse_width_levels", _levels_tuple(self.pulse_width_levels, "descriptors.pulse_width_levels",
                                                       True))
        if self.aoa is not None:
            set_(self, "aoa", _param(self.aoa, "descriptors.aoa"))
            lo, hi = (self.aoa.low, self.aoa.high) if isinstance(self.aoa, Range) else (self.aoa, self.aoa)
            check(0 <= lo and hi <= 360, "descriptors.aoa", self.aoa, "degrees in [0, 360] (None: uniform)")
        set_(self, "aoa_rate", _param(self.aoa_rate, "descriptors.aoa_rate"))
        check(self.scan in SCANS, "descriptors.scan", self.scan, f"one of {', '.join(SCANS)}")
        set_(self, "scan_period", _param(self.scan_period, "descriptors.scan_period", nonneg=True))
        scans = self.scan != "none"
        check(_param_low(self.scan_period) >= MIN_SCAN_PERIOD if scans else self.scan_period == 0,
              "descriptors.scan_period", self.scan_period,
              f"{self.scan} scan needs " + (f"a period >= {MIN_SCAN_PERIOD:g} (TOA units)" if scans else "0"))
        set_(self, "sector", _number(self.sector, "descriptors.sector", 0.0, 360.0))
        check(0 < self.sector < 360 if self.scan == "sector" else self.sector == 0, "descriptors.sector",
              self.sector, "a sector scan needs its width in (0, 360) degrees" if self.scan == "sector"
              else "0 (only a sector scan has a sector)")
        for name in ("beamwidth", "sidelobe_db"):
            set_(self, name, _number(getattr(self, name), f"descriptors.{name}"))
        _check_beam("descriptors", self.beamwidth, self.beam, self.sidelobe_db)

    def frequency_span(self) -> tuple[float, float]:
        """The frequencies its pulses may take before noise (centre range plus hops)."""
        lo, hi = _param_low(self.frequency), _param_high(self.frequency)
        hops = self.frequency_hops or (0.0,)
        return lo + min(hops), hi + max(hops)

    def pulse_width_span(self) -> tuple[float, float]:
        levels = self.pulse_width_levels or (1.0,)
        return _param_low(self.pulse_width) * min(levels), _param_high(self.pulse_width) * max(levels)


@dataclass(frozen=True)
class ReceiverSpec:
    """The receiver of a scenario with pulse descriptors.

    mode: "staring" (fixed gain 1 in every direction) or "scanning" (its look direction turns once per
    `scan_period`, from a direction drawn per episode; its gain is its beam pattern -- `beamwidth`,
    `beam`, `sidelobe_db` as in DescriptorSpec -- at the angle between the look direction and the
    pulse's AoA).  threshold: a pulse whose received amplitude (before measurement noise) is below it
    is not detected: a missing pulse.  frequency_noise_std (MHz), pulse_width_noise_std (us),
    aoa_noise_std (degrees): the receiver's measurement noise on each descriptor.
    """

    mode: str = "staring"
    threshold: float = 0.0
    frequency_noise_std: float = 0.0
    pulse_width_noise_std: float = 0.0
    aoa_noise_std: float = 0.0
    scan_period: float = 0.0
    beamwidth: float = 0.0
    beam: str = "gaussian"
    sidelobe_db: float = -30.0

    def __post_init__(self) -> None:
        check(self.mode in RECEIVER_MODES, "receiver.mode", self.mode, f"one of {', '.join(RECEIVER_MODES)}")
        for name in ("threshold", "frequency_noise_std", "pulse_width_noise_std", "aoa_noise_std", "scan_period",
                     "beamwidth"):
            hi = MAX_DESCRIPTOR if name.endswith("noise_std") else math.inf
            object.__setattr__(self, name, _number(getattr(self, name), f"receiver.{name}", 0.0, hi))
        object.__setattr__(self, "sidelobe_db", _number(self.sidelobe_db, "receiver.sidelobe_db"))
        if self.mode == "scanning":
            check(self.scan_period > 0, "receiver.scan_period", self.scan_period,
                  "a scanning receiver needs a period > 0 (TOA units)")
            _check_beam("receiver", self.beamwidth, self.beam, self.sidelobe_db)
        else:
            check(self.scan_period == 0 and self.beamwidth == 0, "receiver.scan_period",
                  (self.scan_period, self.beamwidth), "scan_period and beamwidth are for mode='scanning' only")
