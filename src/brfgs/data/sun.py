"""The sun of every frame: given per frame, computed from its UTC time (pvlib's NREL SPA), or the scene's.

A multi-angle flight takes 20–60 minutes, in which the sun moves by several degrees. A frame of
``transforms.json`` may therefore carry its own ``sun_zenith_deg`` and ``sun_azimuth_deg``, or a
``time`` (ISO 8601 with a UTC offset, e.g. "2024-06-21T10:32:05Z") from which the sun position
at the scene's ``origin`` is computed with pvlib's implementation of the NREL Solar Position
Algorithm (Reda & Andreas 2004; ``method="nrel_numpy"``; the refraction-corrected topocentric
zenith, which is what SPA reports, and the azimuth clockwise from true north = the ENU frame's
+y). A frame with neither takes the scene's top-level sun.

The scene's *reference* sun (its top-level ``sun_zenith_deg``/``sun_azimuth_deg``, else the sun of
the frame in the middle of the acquisition) is what products and BRF curves use unless asked
otherwise.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from brfgs.data import validation as V
from brfgs.data.georef import Origin
from brfgs.errors import UserError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["solar_position", "frame_suns"]


YEARS = (1900, 2200)  # frame times outside these years are input errors (and outside what pandas holds in ns)


def solar_position(times_utc: list[str] | pd.DatetimeIndex, origin: Origin) -> tuple[np.ndarray, np.ndarray]:
    """(zenith deg, azimuth deg clockwise from north) [N] of the sun at ``origin`` at the given times
    (NREL SPA via pvlib; standard atmosphere at the origin's altitude, 12 °C)."""
    import pandas as pd  # lazy: pvlib and pandas take ~0.6 s to import, and only timed frames need them
    import pvlib  # lazy: as pandas

    t = pd.DatetimeIndex(times_utc)
    pressure = pvlib.atmosphere.alt2pres(origin.altitude_m)
    sp = pvlib.solarposition.get_solarposition(t, origin.latitude_deg, origin.longitude_deg,
                                               altitude=origin.altitude_m, pressure=pressure, temperature=12.0,
                                               method="nrel_numpy")
    return sp["apparent_zenith"].to_numpy(float), sp["azimuth"].to_numpy(float)


def _parse_time(v, tf: Path, field: str) -> pd.Timestamp:
    import pandas as pd  # lazy: as in solar_position

    if isinstance(v, str) and (not v.isascii() or not v.isprintable() or v != v.strip() or len(v) > 64):
        # pandas reads a time with a NUL or a newline after it, other scripts' digits, blanks around
        raise UserError(f"expected an ISO 8601 time written in ASCII characters without control characters or "
                        f"blanks around it, such as '2024-06-21T10:32:05Z', got {v[:80]!r}", file=tf, field=field)
    try:
        t = pd.Timestamp(v) if isinstance(v, str) else None
    except (ValueError, TypeError):
        t = None
    if t is None or t.tzinfo is None:
        raise UserError(f"expected an ISO 8601 time with a UTC offset such as '2024-06-21T10:32:05Z', got {v!r}",
                        file=tf, field=field)
    t = t.tz_convert("UTC")
    if not YEARS[0] <= t.year <= YEARS[1]:
        raise UserError(f"expected a time in the years {YEARS[0]}-{YEARS[1]}, got {v!r}", file=tf, field=field)
    return t


def frame_suns(meta: dict, origin: Origin | None, tf: Path) -> tuple[np.ndarray, np.ndarray, float, float, list]:
    """(zenith [F], azimuth [F], reference zenith, reference azimuth, times [F] or None per frame),
    all degrees, for ``meta["frames"]`` (a list of dicts, checked by the caller)."""
    frames = meta["frames"]
    n = len(frames)
    zen, az, times = np.full(n, np.nan), np.full(n, np.nan), [None] * n
    timed = []
    for k, fm in enumerate(frames):
        fld = f"frames[{k}]"
        has = [fm.get(key) is not None for key in ("sun_zenith_deg", "sun_azimuth_deg")]
        if any(has):
            if not all(has):
                raise UserError("give both sun_zenith_deg and sun_azimuth_deg, or neither", file=tf, field=fld)
            zen[k] = V.number(fm["sun_zenith_deg"], tf, f"{fld}.sun_zenith_deg", lo=0.0, hi=89.999)
            az[k] = V.number(fm["sun_azimuth_deg"], tf, f"{fld}.sun_azimuth_deg", lo=-360.0, hi=360.0)
        if fm.get("time") is not None:
            times[k] = _parse_time(fm["time"], tf, f"{fld}.time")
            if not any(has):
                timed.append(k)
    if timed:
        if origin is None:
            raise UserError("a frame time gives the sun only with the scene's 'origin' (latitude, longitude)",
                            file=tf, field=f"frames[{timed[0]}].time")
        z, a = solar_position([times[k] for k in timed], origin)
        zen[timed], az[timed] = z, a
        if (z >= 89.999).any():
            k = timed[int(np.argmax(z))]
            raise UserError(f"the sun is below the horizon at {times[k].isoformat()} ({z.max():.1f}° zenith)",
                            file=tf, field=f"frames[{k}].time")
    if meta.get("sun_zenith_deg") is not None or meta.get("sun_azimuth_deg") is not None or np.isnan(zen).any():
        for key in ("sun_zenith_deg", "sun_azimuth_deg"):
            if key not in meta:
                raise UserError("required field missing (or give every frame its own sun or time)", file=tf,
                                field=key)
        ref_z = V.number(meta.get("sun_zenith_deg"), tf, "sun_zenith_deg", lo=0.0, hi=89.999)
        ref_a = V.number(meta.get("sun_azimuth_deg"), tf, "sun_azimuth_deg", lo=-360.0, hi=360.0)
        zen[np.isnan(zen)], az[np.isnan(az)] = ref_z, ref_a
    else:                                                       # every frame has its own: the middle one
        order = sorted(range(n), key=lambda k: (times[k] is None, times[k] or 0, k))
        mid = order[len(order) // 2]
        ref_z, ref_a = float(zen[mid]), float(az[mid])
    return zen, az, ref_z, ref_a, times
