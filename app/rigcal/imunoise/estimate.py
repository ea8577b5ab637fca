"""An IMU's noise figures from a checked static recording: per sensor and axis the Allan
deviation and its terms (rigcal.imunoise.terms), combined into Kalibr's four figures."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from rigcal.imunoise.allan import pooled_allan_deviation
from rigcal.imunoise.recording import Checked
from rigcal.imunoise.terms import AxisNoise, TermFit, TooShort, combine, fit_axis

SENSORS = ("gyroscope", "accelerometer")
AXES = ("x", "y", "z")
THREADS = 2  # the axes' Allan deviations are numpy array passes that release the GIL
UNITS = {  # (white noise density, random walk, bias instability)
    "gyroscope": ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)", "rad/s"),
    "accelerometer": ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)", "m/s^2"),
}


@dataclass(frozen=True)
class SensorNoise:
    """One sensor's three axes and its combined figures (the largest axis, `*_axis` its index)."""

    sensor: str
    axes: tuple[AxisNoise, AxisNoise, AxisNoise]
    white: TermFit
    random_walk: TermFit
    bias_instability: TermFit
    white_axis: int
    random_walk_axis: int
    bias_instability_axis: int


@dataclass(frozen=True)
class ImuNoise:
    """The noise figures of one IMU from its static recording."""

    name: str
    checked: Checked
    gyroscope: SensorNoise
    accelerometer: SensorNoise

    def sensors(self) -> tuple[SensorNoise, SensorNoise]:
        return self.gyroscope, self.accelerometer

    def kalibr(self, inflate: float = 1.0) -> dict[str, float]:
        """Kalibr's four figures (times `inflate`)."""
        return {"accelerometer_noise_density": self.accelerometer.white.value * inflate,
                "accelerometer_random_walk": self.accelerometer.random_walk.value * inflate,
                "gyroscope_noise_density": self.gyroscope.white.value * inflate,
                "gyroscope_random_walk": self.gyroscope.random_walk.value * inflate}


def _fit(args) -> AxisNoise:
    parts, rate_hz, what = args
    return fit_axis(pooled_allan_deviation(parts, rate_hz), what)


def _combined(sensor: str, axes: list[AxisNoise]) -> SensorNoise:
    picks = {term: combine([getattr(a, term) for a in axes]) for term in ("white", "random_walk", "bias_instability")}
    return SensorNoise(sensor, tuple(axes), picks["white"][1], picks["random_walk"][1], picks["bias_instability"][1],
                       picks["white"][0], picks["random_walk"][0], picks["bias_instability"][0])


def estimate(name: str, checked: Checked) -> ImuNoise:
    """Both sensors' three axes (THREADS at a time); TooShort naming the source and axis."""
    rec = checked.recording
    runs = checked.segments or (slice(None),)
    jobs = [([data[r, k] for r in runs], checked.rate_hz, f"{sensor} {ax}")
            for sensor, data in zip(SENSORS, (rec.gyro, rec.accel)) for k, ax in enumerate(AXES)]
    try:
        with ThreadPoolExecutor(max_workers=THREADS) as pool:
            axes = list(pool.map(_fit, jobs))
    except TooShort as e:
        raise TooShort(f"{rec.source}: {e}") from None
    return ImuNoise(name, checked, _combined("gyroscope", axes[:3]), _combined("accelerometer", axes[3:]))
