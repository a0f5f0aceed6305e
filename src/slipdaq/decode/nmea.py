"""NMEA 0183: lines -> GpsFix (pynmea2 for syntax and checksum, fields read here).

What the decoder does with what receivers send (checked against gpsd's twelve regression captures in
tests/data/gpsd-nmea: u-blox, SiRF, Quectel, Trimble, Garmin, Telit, OxTS):

- Talkers: any two-letter talker (GP, GN, GL, GA, BD, GB, QZ, ...); the sentence type decides, the talker does not.
- Lines: `#` comment lines and blank lines are ignored and counted (ignored_lines, comment_lines). A line that is not a
  sentence with a good checksum is counted in bad_sentences (binary noise, cut or corrupt sentences, no checksum).
  Noise before a sentence on the same line (`r$GPRMC,...`: lines logged before the framer cut lines at `$`, or given
  by other callers) is skipped when the sentence after the last `$` checks out (resynced_lines). Valid sentences of
  other types (GSV, GSA, TXT, HDT, proprietary $P..., unknown types) are counted in unused_sentences. Nothing here
  raises on any input: a sentence whose handling fails is counted as bad. Every line that gives the estimator nothing
  is counted once in `dropped`, by reason (NmeaDecoder).
- Epoch: the UTC time of day of the latest timed sentence (RMC, GGA, GNS, GLL, ZDA). One GpsFix per epoch at most.
- Speed: from RMC (with NMEA 4.x fields); from VTG only when the receiver sends no RMC (none for VTG_ONLY_AFTER_S host
  seconds), since VTG carries no time and RMC does. A fix is emitted as soon as its sentence arrives (no added latency),
  so "best sentence" means: RMC whenever the receiver sends RMC, else VTG.
- Not double-counted: an RMC or VTG from another talker for an epoch that already has its fix (GNRMC + GPRMC for the
  same time), and VTG beside RMC, are counted in duplicate_sentences. The same talker repeating the same time is a new
  report (receivers without a fix may repeat their time), not a duplicate.
- Validity: RMC status A; the mode indicator (RMC and VTG, NMEA 2.3+), when the sentence has that field, one of a
  GNSS fix (A, D, F, P, R), so not N (no fix), E (dead reckoning), M (manual input), S (simulator) or empty (as
  pynmea2; gpsd ignores an empty one, but a receiver that sends the field and leaves it empty has not said it has a
  fix: in 189 of gpsd's captures, the one receiver that does so sends status V with it); the NMEA 4.1 navigational
  status (last RMC field) not U (unsafe). Its V means "the equipment does not provide a navigational status" (u-blox
  documents it as fixed), not "fix invalid": in those captures 15 receivers (u-blox, Quectel, Furuno, SkyTraq, Telit)
  send V with every valid fix, one (ST Teseo) sends C, none U (gpsd ignores the field and reports those fixes; pynmea2
  would reject all of them). And this epoch's GGA, when it came first, not quality 0 (invalid) or 6 (estimated).
  A sentence with status A but no speed gives no fix (and is counted
  as empty_speed).
- GGA fields (fix quality, satellites, altitude): from this epoch's GGA when it came before the fix; otherwise from the
  previous GGA if it came less than VTG_ONLY_AFTER_S host seconds ago (receivers that send GGA after RMC, e.g. u-blox:
  their fixes carry the previous epoch's GGA fields; a previous epoch's quality never invalidates a fix). With two GGA
  talkers for one epoch (GPGGA + GLGGA), the first is used.
- Time (fix_time_utc_s): the RMC's date and time of day. An RMC without a date (some receivers) takes the last date seen
  in an RMC or ZDA, carried across midnight (of the day before, the same day or the day after, the one whose time is
  nearest the time that date was seen at); with no date known yet it is None. VTG fixes have no time (None). Dates are
  taken as sent: no GPS week-rollover correction (gpsd applies one; see rst39 in tests/test_nmea_receivers.py).
- Speed of decoding: a talker sentence in the plain form (`$` + 5 ASCII word characters + `,` ... `*HH`) is split and
  its checksum checked here; anything else goes through pynmea2. Both give the same result for every line
  (tests/test_nmea_fast.py compares them).
"""

from __future__ import annotations

import datetime as dt
import math
import re
from dataclasses import dataclass
from functools import lru_cache

import pynmea2

from slipdaq.records import GpsFix, NmeaLine

KNOT_MPS = 1852.0 / 3600.0

_DAY_S = 86400.0


# ---- field parsing: the receiver's text, read strictly; anything malformed is None ----

_TOD_RE = re.compile(r"(\d\d)(\d\d)(\d\d(?:\.\d*)?)")
_DM_RE = re.compile(r"(\d{1,3})(\d\d(?:\.\d*)?)")


def _field(data: list[str], i: int) -> str:
    return data[i].strip() if i < len(data) else ""


def _float(value: object) -> float | None:
    """A finite float, or None (empty, malformed, nan, inf)."""
    try:
        x = float(value)  # type: ignore[arg-type]  # any value: float() raising is the check
    except (TypeError, ValueError, OverflowError):
        return None
    return x if math.isfinite(x) else None


def _int(text: str) -> int | None:
    return int(text) if text.isascii() and text.isdigit() else None


@lru_cache(maxsize=64)  # RMC and GGA of one epoch carry the same time, every RMC the same date
def _tod(text: str) -> float | None:
    """`hhmmss[.sss]` -> seconds of the UTC day, rounded to the microsecond."""
    m = _TOD_RE.fullmatch(text)
    if m is None:
        return None
    h, mi, s = int(m[1]), int(m[2]), float(m[3])
    if h > 23 or mi > 59 or s >= 61.0:
        return None
    return round(h * 3600 + mi * 60 + s, 6)


@lru_cache(maxsize=64)
def _ddmmyy(text: str) -> dt.date | None:
    if len(text) != 6 or not (text.isascii() and text.isdigit()):
        return None
    yy = int(text[4:])
    try:  # as strptime's %d%m%y: 69-99 -> 19xx, 00-68 -> 20xx
        return dt.date(1900 + yy if yy >= 69 else 2000 + yy, int(text[2:4]), int(text[:2]))
    except ValueError:
        return None


def _degrees(value: str, hemisphere: str, limit: float) -> float | None:
    """`dddmm.mmmm` plus N/S/E/W -> signed degrees."""
    m = _DM_RE.fullmatch(value)
    if m is None or hemisphere.upper() not in ("N", "S", "E", "W"):
        return None
    minutes = float(m[2])
    deg = int(m[1]) + minutes / 60.0
    if minutes >= 60.0 or deg > limit:
        return None
    return -deg if hemisphere.upper() in ("S", "W") else deg


_EPOCH_ORDINAL = dt.date(1970, 1, 1).toordinal()


def _utc(date: dt.date, tod: float) -> float:
    return (date.toordinal() - _EPOCH_ORDINAL) * 86400 + tod  # = calendar.timegm(date.timetuple()) + tod


@dataclass(frozen=True, slots=True)
class _Gga:
    talker: str
    host_s: float
    quality: int | None
    satellites: int | None
    altitude_m: float | None


# ---- the fast path: what pynmea2.parse(line, check=True) gives for a talker sentence in the plain form ----

_PLAIN_RE = re.compile(
    r"\$([A-OQ-Za-oq-z0-9_][A-Za-z0-9_])([A-Za-z0-9_]{2}[A-PR-Za-pr-z0-9_]),([^*]*)\*([0-9A-Fa-f]{2})"
)
"""`$` + talker (not P..., pynmea2's proprietary form) + type (not ..Q, its query form) + `,` data `*HH`."""
DECODED_TYPES = frozenset({"RMC", "VTG", "GGA", "ZDA", "GNS", "GLL"})
"""The sentence types NmeaDecoder reads; every other checked sentence is counted as unsupported."""
_BAD = object()
_UNKNOWN = "unknown"


def _xor_checksum(text: str) -> int:
    """XOR of the characters' code points, as pynmea2 computes the checksum."""
    if not text.isascii():
        x = 0
        for ch in text:
            x ^= ord(ch)
        return x
    x = int.from_bytes(text.encode("ascii"), "little")
    k, bits = 8, 8 * len(text)
    while k < bits:  # fold: byte 0 becomes the XOR of all bytes
        x ^= x >> k
        k <<= 1
    return x & 0xFF


def _parse_plain(candidate: str) -> tuple[str, str, list[str]] | str | object | None:
    """(talker, type, fields), _UNKNOWN or _BAD as pynmea2 would decide; None when this form is not handled here."""
    m = _PLAIN_RE.fullmatch(candidate)
    if m is None:
        return None
    if _xor_checksum(candidate[1:-3]) != int(m[4], 16):
        return _BAD  # pynmea2: ChecksumError
    kind = m[2].upper()
    if kind in DECODED_TYPES:
        return m[1].upper(), kind, m[3].split(",")
    return _UNKNOWN  # unsupported whether pynmea2 knows the type or not


_INVALID_GGA_QUALITY = (0, 6)  # 0 = no fix, 6 = estimated (dead reckoning)
_FIX_MODES = ("A", "D", "F", "P", "R")
"""FAA mode indicators (NMEA 2.3+) of a GNSS fix: autonomous, differential, RTK float, precise, RTK integer. Not:
N (not valid), E (estimated: dead reckoning), M (manual input), S (simulator), empty, or anything else."""
_UNSAFE_NAV_STATUS = "U"
"""NMEA 4.1 navigational status U (unsafe): the receiver's integrity monitoring says do not use it. S (safe),
C (caution) and V ("navigational status not valid": the equipment does not provide one; u-blox and Quectel always
send V with their valid fixes) leave validity to status and mode."""
_RMC_MODE, _RMC_NAV_STATUS, _VTG_MODE = 11, 12, 8  # field indexes after the address field

DROP_REASONS = (
    "bad_checksum", "unparsable", "unsupported", "duplicate",
    "status_void", "mode_invalid", "nav_status_unsafe", "gga_invalid", "empty_speed",
)
"""Why a line gave the estimator nothing (NmeaDecoder.dropped): see the class docstring."""
_TIMED = ("RMC", "GGA", "GNS", "GLL", "ZDA")


class NmeaDecoder:
    """Stateful, pure: NMEA lines in arrival order -> GpsFix per epoch, with counters.

    Counters: lines = ignored_lines + bad_sentences + sentences. Of the sentences (checksum good), unused_sentences are
    of types not used and duplicate_sentences were not used because their epoch has its speed from another sentence.
    comment_lines is the part of ignored_lines that starts with `#`; resynced_lines the sentences decoded after noise.

    dropped counts, by reason, every line that is not ignored and gave the estimator nothing (no valid fix, and no
    epoch, date or GGA fields either), under one reason:
    bad_checksum (wrong or missing checksum) and unparsable (not a sentence: noise, cut, or fields that broke the
    handling) make bad_sentences; unsupported (a type not used) is unused_sentences; duplicate is duplicate_sentences;
    then the RMC and VTG that give no valid fix, under the first of: status_void (RMC status not A), mode_invalid (a
    mode indicator not in _FIX_MODES), nav_status_unsafe (NMEA 4.1 status U), gga_invalid (this epoch's GGA, sent
    before it, says quality 0 or 6), empty_speed (valid, but no speed: empty, malformed or negative). An invalid
    sentence with a speed is still a GpsFix (valid=False: logged, and skipped by the estimator).
    """

    VTG_ONLY_AFTER_S = 1.5
    """VTG gives the speed only when no RMC has come for this long (no double counting)."""
    COUNTERS = ("lines", "sentences", "ignored_lines", "fixes", "comment_lines", "resynced_lines")
    """Its running counts (ints), besides `dropped` (by DROP_REASONS)."""

    def __init__(self, fast_path: bool = True) -> None:
        """fast_path=False sends every sentence through pynmea2 (the reference the fast path is tested against)."""
        self._fast_path = fast_path
        self.lines = 0
        self.sentences = 0
        self.ignored_lines = 0
        self.fixes = 0
        self.comment_lines = 0
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self.resynced_lines = 0
        self._last_rmc_s: float | None = None
        self._epoch_tod: float | None = None
        self._epoch_fix: tuple[str, str] | None = None  # (talker, type) of the sentence that gave this epoch's fix
        self._epoch_gga: _Gga | None = None
        self._last_gga: _Gga | None = None
        self._date: dt.date | None = None
        self._date_tod = 0.0

    @property
    def bad_sentences(self) -> int:
        """Lines that are not a sentence with a good checksum (and checked sentences whose handling failed)."""
        return self.dropped["bad_checksum"] + self.dropped["unparsable"]

    @property
    def unused_sentences(self) -> int:
        return self.dropped["unsupported"]

    @property
    def duplicate_sentences(self) -> int:
        return self.dropped["duplicate"]

    # ---- entry point ----

    def decode(self, line: NmeaLine) -> GpsFix | None:
        """One line -> a GpsFix when it completes an epoch's speed, else None. Never raises on any input."""
        self.lines += 1
        try:
            text = str(line.line).strip()
            timestamp_s = float(line.timestamp_s)
        except Exception:  # not even a line: count it, never raise
            self._drop("unparsable")
            return None
        if not text or text.startswith("#"):
            self.ignored_lines += 1
            self.comment_lines += text.startswith("#")
            return None
        msg = self._parse(text)
        if msg is _BAD or msg is None:
            self._drop("bad_checksum" if msg is _BAD else "unparsable")
            return None
        self.sentences += 1
        try:
            return self._dispatch(msg, timestamp_s)
        except Exception:  # a checked sentence whose fields broke the handling: counted as bad, never raised
            self.sentences -= 1  # (the handlers count a drop only as their last step, when nothing can raise)
            self._drop("unparsable")
            return None

    def _drop(self, reason: str) -> None:
        self.dropped[reason] += 1

    def _parse(self, text: str) -> tuple[str, str, list[str]] | pynmea2.NMEASentence | str | object | None:
        """(talker, type, fields) or the pynmea2 sentence; "unknown" for a good sentence of a type pynmea2 does not
        know; _BAD when no candidate parsed and one failed its checksum (or had none); None when none parsed."""
        checksum_failed = False
        candidates = [text]
        cut = text.rfind("$")
        if cut > 0:  # noise before the sentence, or a sentence whose line end was lost
            candidates.append(text[cut:])
        for i, candidate in enumerate(candidates):
            msg = _parse_plain(candidate) if self._fast_path else None
            if msg is _BAD:
                checksum_failed = True
                continue
            if msg is None:
                try:
                    msg = pynmea2.parse(candidate, check=True)
                except pynmea2.SentenceTypeError:  # checksum was good (checked first), the type is unknown to pynmea2
                    msg = _UNKNOWN
                except pynmea2.ChecksumError:  # wrong or missing
                    checksum_failed = True
                    continue
                except Exception:  # pynmea2 raises ParseError, and odd ones on odd input
                    continue
            self.resynced_lines += i > 0
            return msg
        return _BAD if checksum_failed else None

    def _dispatch(
        self, msg: tuple[str, str, list[str]] | pynmea2.NMEASentence | str, timestamp_s: float,
    ) -> GpsFix | None:
        if type(msg) is tuple:
            talker, kind, data = msg
        elif isinstance(msg, pynmea2.TalkerSentence):
            kind = str(getattr(msg, "sentence_type", "")).upper()
            talker = str(getattr(msg, "talker", "")).upper()
            data = [str(x) for x in msg.data]
        else:
            self._drop("unsupported")
            return None
        if kind == "RMC":
            return self._rmc(talker, data, timestamp_s)
        if kind == "VTG":
            return self._vtg(talker, data, timestamp_s)
        if kind == "GGA":
            self._gga(talker, data, timestamp_s)
        elif kind == "ZDA":
            self._zda(data)
        elif kind == "GNS":
            self._enter_epoch(_tod(_field(data, 0)))
        elif kind == "GLL":
            self._enter_epoch(_tod(_field(data, 4)))
        else:
            self._drop("unsupported")
        return None

    # ---- epochs, dates, GGA ----

    def _enter_epoch(self, tod: float | None) -> None:
        """A timed sentence: a new time of day starts a new epoch; a sentence without time stays in the current one."""
        if tod is None or tod == self._epoch_tod:
            return
        self._epoch_tod = tod
        self._epoch_fix = None
        self._epoch_gga = None

    def _claim_epoch(self, talker: str, kind: str) -> bool:
        """True when this sentence gives the epoch's fix; False (counted) when the epoch has one from another sentence.

        The same talker and type again within one epoch is a new report (the receiver repeated its time), not a
        duplicate; another talker or type is a duplicate (GNRMC + GPRMC for the same time, VTG after RMC).
        """
        key = (talker, kind)
        if self._epoch_fix is not None and self._epoch_fix != key:
            self._drop("duplicate")
            return False
        self._epoch_fix = key
        return True

    def _remember_date(self, date: dt.date, tod: float) -> None:
        self._date, self._date_tod = date, tod

    def _date_for(self, tod: float) -> dt.date | None:
        """The date of a time of day with no date of its own: the remembered date, carried across midnight."""
        if self._date is None:
            return None
        k = min((-1, 0, 1), key=lambda d: abs(tod + d * _DAY_S - self._date_tod))
        date = self._date + dt.timedelta(days=k)
        self._remember_date(date, tod)
        return date

    def _gga(self, talker: str, data: list[str], timestamp_s: float) -> None:
        tod = _tod(_field(data, 0))
        self._enter_epoch(tod)
        gga = _Gga(
            talker=talker,
            host_s=timestamp_s,
            quality=_int(_field(data, 5)),
            satellites=_int(_field(data, 6)),
            altitude_m=_float(_field(data, 8)),
        )
        if self._epoch_gga is not None and self._epoch_gga.talker != talker and tod is not None:
            self._drop("duplicate")  # a second talker's GGA for the same epoch (GPGGA + GLGGA): the first is used
            return
        self._epoch_gga = gga
        self._last_gga = gga

    def _zda(self, data: list[str]) -> None:
        tod = _tod(_field(data, 0))
        self._enter_epoch(tod)
        day, month, year = _int(_field(data, 1)), _int(_field(data, 2)), _int(_field(data, 3))
        if tod is None or day is None or month is None or year is None or year < 1980:
            return
        try:
            self._remember_date(dt.date(year, month, day), tod)
        except ValueError:
            pass

    def _gga_for_fix(self, timestamp_s: float) -> tuple[_Gga | None, bool]:
        """GGA fields for a fix, and whether they are this epoch's own (only those can invalidate it)."""
        if self._epoch_gga is not None:
            return self._epoch_gga, True
        last = self._last_gga
        if last is not None and 0.0 <= timestamp_s - last.host_s < self.VTG_ONLY_AFTER_S:
            return last, False
        return None, False

    def _why_invalid(
        self, data: list[str], timestamp_s: float, mode_at: int, status: str | None = None, nav_at: int | None = None,
    ) -> str | None:
        """Why a speed sentence gives no valid fix (a DROP_REASONS entry), or None when it does. A mode indicator or
        navigational status field that the sentence does not have (an older NMEA version) does not count."""
        if status is not None and status.upper() != "A":
            return "status_void"
        if len(data) > mode_at and _field(data, mode_at).upper() not in _FIX_MODES:
            return "mode_invalid"
        if nav_at is not None and _field(data, nav_at).upper() == _UNSAFE_NAV_STATUS:
            return "nav_status_unsafe"
        gga, own = self._gga_for_fix(timestamp_s)
        if gga is not None and own and gga.quality in _INVALID_GGA_QUALITY:
            return "gga_invalid"
        return None

    def _fix(self, timestamp_s: float, speed_mps: float, invalid: str | None, sentence: str, **kw: object) -> GpsFix:
        """The epoch's fix; one that is not valid is counted as dropped for its reason."""
        gga, _own = self._gga_for_fix(timestamp_s)
        fix = GpsFix(
            timestamp_s=timestamp_s,
            speed_mps=speed_mps,
            valid=invalid is None,
            sentence=sentence,
            fix_quality=gga.quality if gga else None,
            satellites=gga.satellites if gga else None,
            altitude_m=gga.altitude_m if gga else None,
            **kw,  # type: ignore[arg-type]  # the fields' types are checked where they are parsed
        )
        self.fixes += 1
        if invalid is not None:
            self._drop(invalid)
        return fix

    # ---- speed sentences ----

    def _rmc(self, talker: str, data: list[str], timestamp_s: float) -> GpsFix | None:
        tod = _tod(_field(data, 0))
        self._enter_epoch(tod)
        self._last_rmc_s = timestamp_s
        date = _ddmmyy(_field(data, 8))
        if date is not None and tod is not None:
            self._remember_date(date, tod)
        speed_kn = _float(_field(data, 6))
        invalid = self._why_invalid(data, timestamp_s, _RMC_MODE, _field(data, 1), _RMC_NAV_STATUS)
        if speed_kn is None or speed_kn < 0:
            self._drop(invalid or "empty_speed")
            return None
        if not self._claim_epoch(talker, "RMC"):
            return None
        if tod is None:
            fix_time = None
        else:
            day = date if date is not None else self._date_for(tod)
            fix_time = _utc(day, tod) if day is not None else None
        course = _float(_field(data, 7))
        return self._fix(
            timestamp_s,
            speed_kn * KNOT_MPS,
            invalid,
            "RMC",
            fix_time_utc_s=fix_time,
            course_deg=course,
            latitude_deg=_degrees(_field(data, 2), _field(data, 3), 90.0),
            longitude_deg=_degrees(_field(data, 4), _field(data, 5), 180.0),
        )

    def _vtg(self, talker: str, data: list[str], timestamp_s: float) -> GpsFix | None:
        if self._last_rmc_s is not None and timestamp_s - self._last_rmc_s < self.VTG_ONLY_AFTER_S:
            self._drop("duplicate")  # the receiver sends RMC, the better sentence (it has the time)
            return None
        kmph = _float(_field(data, 6))
        speed_mps = kmph / 3.6 if kmph is not None and kmph >= 0 else None
        if speed_mps is None:
            kn = _float(_field(data, 4))
            speed_mps = kn * KNOT_MPS if kn is not None and kn >= 0 else None
        invalid = self._why_invalid(data, timestamp_s, _VTG_MODE)
        if speed_mps is None:
            self._drop(invalid or "empty_speed")
            return None
        if not self._claim_epoch(talker, "VTG"):
            return None
        return self._fix(
            timestamp_s,
            speed_mps,
            invalid,
            "VTG",
            course_deg=_float(_field(data, 0)),
        )
