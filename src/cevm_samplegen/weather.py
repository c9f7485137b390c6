"""The weather of the sample logs: air temperature and sunshine over Milton Keynes (pure).

Every logging day gets its own weather, drawn from the seed and the date alone (so every
vehicle out on that day sees the same air):

* **Daily mean** = the seasonal mean of the place, a cosine over the year between
  :attr:`Climate.mean_jan_c` and :attr:`Climate.mean_jul_c` with its minimum on
  :attr:`Climate.coldest_day_of_year`, plus the day's weather anomaly, normal with
  standard deviation :attr:`Climate.anomaly_sd_k`.
* **Cloud** c in 0..1 for the day, Beta(2.6, 1.4) (mean 0.65: the English Midlands are
  mostly cloudy); it sets the sunshine (clear-sky index 1 - 0.8 c^2, with a 20-minute
  AR(1) variation of 0.15 for passing clouds) and the diurnal range, seasonal
  (:attr:`Climate.range_winter_k` to :attr:`Climate.range_summer_k`) times 1.45 - 0.7 c:
  clear days have cold nights and warm afternoons.
* **Diurnal cycle**: the minimum half an hour after sunrise, the maximum 2.5 h after solar
  noon, half cosines between them (rising, then falling to the next morning's minimum),
  the usual two-part shape of daily temperature models. Trips that start the evening
  before belong to the day's weather (the cycle is periodic in 24 h).
* **Noise**: AR(1), standard deviation :attr:`Climate.noise_sd_k`, correlation time
  :attr:`Climate.noise_tau_s`, on a 60 s grid (gusts, showers, urban heat).
* **Forced days** (:class:`ForcedDay`): a cold or hot day given by its minimum, maximum and
  cloud (the cold snap of late January 2019 and the heat of 25 July 2019 really
  happened); their noise and passing clouds are drawn as on any other day.

Sunshine is global horizontal irradiance [W/m^2]: Haurwitz's clear-sky model, 1098 sin(a)
exp(-0.057 / sin(a)) at solar elevation a (declination and equation of time from the
usual Spencer-type approximations), times the clear-sky index. Not simulated: wind,
humidity, rain, frost on windows, the urban heat island as such.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np

from cevm.units import S_PER_H
from cevm_samplegen.common import seeded_rng

_GRID_S = 60.0
_DAY_S = 86400.0


@dataclass(frozen=True)
class Climate:
    """A place's climate, as the generator draws weather from it.

    Defaults: Milton Keynes (52.04 N, 0.76 W). Met Office 1991-2020 averages of the
    nearby stations (Woburn, Bedford) are about 4-4.5 degC in January and 17-17.5 degC
    in July, with mean diurnal ranges of about 6 K in winter and 10 K in summer; daily
    means scatter about 2.5 K around the season's (one standard deviation).
    """

    lat_deg: float = 52.04
    lon_deg: float = -0.76
    mean_jan_c: float = 4.2
    mean_jul_c: float = 17.2
    coldest_day_of_year: float = 20.0
    range_winter_k: float = 6.0
    range_summer_k: float = 10.0
    anomaly_sd_k: float = 2.5
    noise_sd_k: float = 0.25
    noise_tau_s: float = 1200.0

    def seasonal_mean_c(self, day_of_year: float) -> float:
        """Mean air temperature of a day of the year [degC] (coldest on
        :attr:`coldest_day_of_year`, warmest half a year later)."""
        mid = 0.5 * (self.mean_jan_c + self.mean_jul_c)
        amp = 0.5 * (self.mean_jul_c - self.mean_jan_c)
        return mid - amp * math.cos(2.0 * math.pi * (day_of_year - self.coldest_day_of_year) / 365.25)

    def seasonal_range_k(self, day_of_year: float) -> float:
        """Diurnal range (max - min) of an average day [K]."""
        mid = 0.5 * (self.range_winter_k + self.range_summer_k)
        amp = 0.5 * (self.range_summer_k - self.range_winter_k)
        return mid - amp * math.cos(2.0 * math.pi * (day_of_year - self.coldest_day_of_year) / 365.25)


MILTON_KEYNES = Climate()


@dataclass(frozen=True)
class ForcedDay:
    """A day whose weather is given, not drawn: ISO date, minimum and maximum air
    temperature [degC], cloud 0..1."""

    date: str
    min_c: float
    max_c: float
    cloud: float


def _solar(day_of_year: float, lat_deg: float, lon_deg: float):
    """(declination [rad], equation of time [h]) of a day."""
    decl = math.radians(23.44) * math.sin(2.0 * math.pi * (284.0 + day_of_year) / 365.0)
    b = 2.0 * math.pi * (day_of_year - 81.0) / 364.0
    eot_h = (9.87 * math.sin(2 * b) - 7.53 * math.cos(b) - 1.5 * math.sin(b)) / 60.0
    return decl, eot_h


@dataclass(frozen=True, eq=False)
class DayWeather:
    """The weather of one day: its temperature extremes, cloud, sun times and the noise
    of its air temperature and sunshine (on a 60 s grid from 12 h before midnight UTC to
    36 h after).

    :meth:`ambient_c` and :meth:`solar_w_m2` take absolute UTC times [s since 1970].
    """

    date: str
    min_c: float
    max_c: float
    cloud: float
    forced: bool
    climate: Climate
    midnight_utc_s: float
    sunrise_utc_h: float
    solar_noon_utc_h: float
    declination_rad: float
    eot_h: float
    noise_k: np.ndarray
    sky_noise: np.ndarray

    @property
    def mean_c(self) -> float:
        return 0.5 * (self.min_c + self.max_c)

    def _grid(self, utc_s, values: np.ndarray) -> np.ndarray:
        x = (np.asarray(utc_s, dtype=np.float64) - (self.midnight_utc_s - 0.5 * _DAY_S)) / _GRID_S
        return np.interp(x, np.arange(values.size, dtype=np.float64), values)

    def ambient_c(self, utc_s) -> np.ndarray:
        """Air temperature [degC] at UTC times ``utc_s`` [s]."""
        h = (np.asarray(utc_s, dtype=np.float64) - self.midnight_utc_s) / S_PER_H
        t_min = self.sunrise_utc_h + 0.5
        t_max = self.solar_noon_utc_h + 2.5
        x = np.mod(h - t_min, 24.0)  # hours since this cycle's minimum
        rise = t_max - t_min
        shape = np.where(x < rise, -np.cos(np.pi * x / rise), np.cos(np.pi * (x - rise) / (24.0 - rise)))
        return self.mean_c + 0.5 * (self.max_c - self.min_c) * shape + self._grid(utc_s, self.noise_k)

    def solar_elevation_sin(self, utc_s) -> np.ndarray:
        """Sine of the solar elevation at UTC times ``utc_s`` [s]."""
        h = (np.asarray(utc_s, dtype=np.float64) - self.midnight_utc_s) / S_PER_H
        omega = np.radians(15.0 * (h + self.climate.lon_deg / 15.0 + self.eot_h - 12.0))
        phi = math.radians(self.climate.lat_deg)
        d = self.declination_rad
        return math.sin(phi) * math.sin(d) + math.cos(phi) * math.cos(d) * np.cos(omega)

    def solar_w_m2(self, utc_s) -> np.ndarray:
        """Global horizontal irradiance [W/m^2] at UTC times ``utc_s`` [s]."""
        s = self.solar_elevation_sin(utc_s)
        clear = np.where(s > 0.01, 1098.0 * s * np.exp(-0.057 / np.maximum(s, 0.01)), 0.0)
        index = np.clip(1.0 - 0.8 * self.cloud**2 + self._grid(utc_s, self.sky_noise), 0.1, 1.0)
        return clear * index


def _ar1_grid(n: int, tau_steps: float, sd: float, rng: np.random.Generator) -> np.ndarray:
    a = math.exp(-1.0 / tau_steps)
    w = rng.normal(0.0, sd * math.sqrt(1.0 - a * a), n)
    w[0] = rng.normal(0.0, sd)
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], w)


def day_weather(date: str, seed: int, forced: ForcedDay | None = None, climate: Climate = MILTON_KEYNES) -> DayWeather:
    """The weather of ``date`` (ISO) for ``seed``: drawn from ``climate`` unless
    ``forced`` gives it. Pure: the same arguments give the same weather."""
    day = datetime.fromisoformat(date).replace(tzinfo=UTC)
    doy = float(day.timetuple().tm_yday)
    rng = seeded_rng(seed, "weather", date)
    anomaly = float(rng.normal(0.0, climate.anomaly_sd_k))
    cloud = float(rng.beta(2.6, 1.4))
    n = int(2.0 * _DAY_S / _GRID_S) + 1
    noise = _ar1_grid(n, climate.noise_tau_s / _GRID_S, climate.noise_sd_k, rng)
    sky = _ar1_grid(n, 1200.0 / _GRID_S, 0.15, rng)
    if forced is not None:
        if forced.date != date:
            raise ValueError(f"forced weather of {forced.date} given for {date}")
        if not forced.max_c >= forced.min_c or not 0.0 <= forced.cloud <= 1.0:
            raise ValueError(f"forced weather of {date}: need max_c >= min_c and cloud in 0..1")
        t_min, t_max, cloud = forced.min_c, forced.max_c, forced.cloud
    else:
        mean = climate.seasonal_mean_c(doy) + anomaly
        rng_k = climate.seasonal_range_k(doy) * (1.45 - 0.7 * cloud)
        t_min, t_max = mean - 0.5 * rng_k, mean + 0.5 * rng_k
    decl, eot_h = _solar(doy, climate.lat_deg, climate.lon_deg)
    phi = math.radians(climate.lat_deg)
    omega0_h = math.degrees(math.acos(max(-1.0, min(1.0, -math.tan(phi) * math.tan(decl))))) / 15.0
    noon = 12.0 - climate.lon_deg / 15.0 - eot_h
    return DayWeather(
        date=date, min_c=float(t_min), max_c=float(t_max), cloud=float(cloud), forced=forced is not None,
        climate=climate, midnight_utc_s=day.timestamp(), sunrise_utc_h=noon - omega0_h, solar_noon_utc_h=noon,
        declination_rad=decl, eot_h=eot_h, noise_k=noise, sky_noise=sky,
    )
