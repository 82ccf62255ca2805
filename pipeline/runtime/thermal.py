"""Steady-state conductor temperature from its current, after IEEE Std 738 (SI form):
the temperature Tc at which the heat gained equals the heat lost,

    I^2 R(Tc) + q_s = q_c(Tc) + q_r(Tc)        (W per metre of conductor)

- R(Tc): AC resistance interpolated linearly between two temperatures (the tables'
  25 and 75 deg C figures), ohm/m;
- q_s = absorptivity x irradiance x D (the sun on the projected area);
- q_c: the largest of the two forced-convection correlations (low and high Reynolds
  number) and natural convection, with the air's viscosity, density (at the
  elevation) and conductivity at the film temperature (Tc + Ta) / 2, wind across the
  conductor;
- q_r = 17.8 D emissivity ((Tc + 273) / 100)^4 - ((Ta + 273) / 100)^4).
Solved by a bracketed root search (the net heat loss rises with Tc). Pure math.
"""

from __future__ import annotations


def air(film_c: float, elevation_m: float) -> tuple[float, float, float]:
    """Dynamic viscosity (Pa s), density (kg/m^3) and thermal conductivity (W/(m K))
    of air at the film temperature and elevation (IEEE 738 equations 13a, 14a, 15a)."""
    mu = 1.458e-6 * (film_c + 273.0) ** 1.5 / (film_c + 383.4)
    rho = (1.293 - 1.525e-4 * elevation_m + 6.379e-9 * elevation_m ** 2) / (1.0 + 0.00367 * film_c)
    k = 2.424e-2 + 7.477e-5 * film_c - 4.407e-9 * film_c ** 2
    return mu, rho, k


def heat_loss(tc: float, ta: float, diameter_m: float, wind_m_s: float, emissivity: float,
              elevation_m: float = 0.0) -> float:
    """Convective plus radiative loss, W/m, of a conductor at tc (deg C) in air at ta."""
    dt = tc - ta
    if dt <= 0:
        return dt  # no loss below the air's temperature (kept monotonic for the root search)
    mu, rho, k = air((tc + ta) / 2.0, elevation_m)
    re = diameter_m * rho * max(wind_m_s, 0.0) / mu
    forced = max((1.01 + 1.35 * re ** 0.52) * k * dt, 0.754 * re ** 0.6 * k * dt)
    natural = 3.645 * rho ** 0.5 * diameter_m ** 0.75 * dt ** 1.25
    radiated = 17.8 * diameter_m * emissivity * (((tc + 273.0) / 100.0) ** 4 - ((ta + 273.0) / 100.0) ** 4)
    return max(forced, natural) + radiated


def temperature(current_a: float, ambient_c: float, *, diameter_m: float, r25_ohm_per_km: float,
                r75_ohm_per_km: float, wind_m_s: float = 0.6, irradiance_w_m2: float = 0.0,
                emissivity: float = 0.5, absorptivity: float = 0.5, elevation_m: float = 0.0) -> float:
    """Steady-state conductor temperature (deg C) of one subconductor carrying
    `current_a` (A rms) in air at `ambient_c`."""
    slope = (r75_ohm_per_km - r25_ohm_per_km) / 50.0 / 1000.0
    r25 = r25_ohm_per_km / 1000.0
    gain_sun = absorptivity * max(irradiance_w_m2, 0.0) * diameter_m

    def net(tc: float) -> float:
        resistance = r25 + slope * (tc - 25.0)
        return heat_loss(tc, ambient_c, diameter_m, wind_m_s, emissivity, elevation_m) - current_a ** 2 * resistance - gain_sun

    hi = ambient_c + 10.0
    while net(hi) < 0:
        hi += 50.0
        if hi > ambient_c + 2000.0:
            raise ValueError(f"{current_a:g} A: no steady state below {hi:g} C (runaway)")
    # imported here: scipy.optimize is slow to import, and not every process that
    # imports the runtime's nodes solves a conductor's temperature
    from scipy.optimize import brentq

    return brentq(net, ambient_c - 1e-9, hi, xtol=1e-9)

