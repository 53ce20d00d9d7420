"""The simulator's own statement of the facts its files encode, written apart from the readers.

The simulator checks the readers and the georeferencing, so it must not take
their constants or conventions from them: a wrong lever arm in the readers'
mounting table, a wrong GPS epoch or a wrong NMEA checksum would otherwise be
written into the simulated files and read back "correctly".  Each value
here is copied from its source document, not from ``stages.parse``.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

#: Seed 0, Tabla 15 "Distintas configuraciones de montaje": MPOS_X, MPOS_Y, MPOS_Z in metres, the
#: position of the LD-MRS origin in the MTi-G frame for the three mountings of the source document.
TABLE_15_MOUNTINGS: dict[str, tuple[float, float, float]] = {
    "laboratorio": (-0.0027, -0.0221, -0.0535),
    "pilatus": (-0.023, 0.0514, -0.1365),
    "cb5000": (0.013, 0.0299, -0.0565),
}

#: Start of GPS time (IS-GPS-200, §3.3.4: midnight of 5/6 January 1980, UTC).
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=UTC)


def gps_seconds(utc: datetime, leap_seconds: float) -> float:
    """Seconds since :data:`GPS_EPOCH` of a UTC instant: GPS time runs ahead of UTC by the leap seconds.

    >>> gps_seconds(datetime(1980, 1, 6, tzinfo=UTC), 0)
    0.0
    >>> gps_seconds(datetime(2017, 1, 1, tzinfo=UTC), 18) - gps_seconds(datetime(2016, 12, 31, tzinfo=UTC), 18)
    86400.0
    """
    return (utc - GPS_EPOCH) / timedelta(seconds=1) + leap_seconds


def nmea_sentence(body: str) -> str:
    """``$`` + *body* + ``*hh``: NMEA 0183 §5.2.1, the checksum the XOR of every character of *body*.

    The GGA example of the NMEA tutorials (gpsd's "NMEA Revealed"), checksum 47:

    >>> nmea_sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
    '$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47'
    """
    checksum = 0
    for byte in body.encode("ascii"):
        checksum ^= byte
    return f"${body}*{checksum:02X}"


def utm_epsg(lon: float, lat: float) -> int:
    """EPSG code of the WGS 84 / UTM zone of a point (zones of 6° from 180° W; no Norway/Svalbard exceptions).

    >>> utm_epsg(-3.7, 40.4), utm_epsg(151.2, -33.9)
    (32630, 32756)
    """
    zone = int((lon + 180.0) // 6.0) % 60 + 1
    return (32600 if lat >= 0 else 32700) + zone
