"""Field types the request schemas share: what may be a name in a URL, a commit, a time.

Each refuses at the edge (422 naming the field) what could be stored but not used afterwards:
a title no URL can address, a date Python cannot read back, a commit git would read as an option.
"""

from __future__ import annotations

import math
import re
import unicodedata
from datetime import UTC, datetime, timedelta
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator, Field

#: commit times accepted: from the Unix epoch to a year ahead (a skewed clock, not a typo)
EARLIEST = datetime(1970, 1, 1, tzinfo=UTC)
FUTURE_SLACK = timedelta(days=366)
#: what no name or line of text may hold: controls (CR, LF, NUL, and C1's U+0085, a line break
#: to some readers), line and paragraph separators, and the bidi controls (U+202E shows what
#: follows reversed); a trial's CR/LF printed a second row in a table. Other format characters
#: (a ZWJ in an emoji, a ZWNJ in a Persian word) are text
_UNSEEN = frozenset({"Cc", "Zl", "Zp"})
_BIDI = frozenset("\u200e\u200f\u061c") | {
    chr(c) for c in (*range(0x202A, 0x202F), *range(0x2066, 0x206A))
}


def _unseen(char: str) -> bool:
    return char in _BIDI or unicodedata.category(char) in _UNSEEN


def _refuse_first(value: str, spaces: bool) -> str:
    for position, char in enumerate(value):
        if _unseen(char) or (spaces and char.isspace()):
            raise ValueError(f"must not contain {char!r} at position {position}")
    return value


def escaped(text: str) -> str:
    """``text`` with each character `one_line` refuses written as its escape (``\\u202e``): how
    a refusal quotes the input it refused, which would otherwise reverse or break the line
    it is read in."""
    return "".join(
        char.encode("unicode_escape").decode() if _unseen(char) else char for char in text
    )


def one_line(value: str) -> str:
    """``value`` if it shows as one line of what it holds (spaces allowed), else a ValueError
    naming its first control, format or line-separator character and its position."""
    return _refuse_first(value, spaces=False)


def printable(value: str) -> str:
    """``value`` as `one_line`, and without a space (a header's or URL's would break it or be
    refused at each use)."""
    return _refuse_first(value, spaces=True)


def path_segment(value: str) -> str:
    """A value that is one URL path segment: no ``/``, one line, not ``.``/``..``."""
    if "/" in value:
        raise ValueError("must not contain '/' (it names one path segment of the API's URLs)")
    if value in (".", ".."):
        raise ValueError(f"{value!r} cannot be addressed in a URL")
    return one_line(value)


def host_name(value: str) -> str:
    """A performance host's name: `printable` ASCII, one word without '/' (a pool token's replica
    named itself 'compose-../../x'; a 'perf-ü1' registered, but no upload's X-Redline-Host
    header could carry its name, and every upload of its runs was refused)."""
    if "/" in value:
        raise ValueError("must not contain '/': a host's name is one machine's name")
    printable(value)  # its unseen characters named first, as every other field's are
    for position, char in enumerate(value):
        if not char.isascii():
            raise ValueError(
                f"must be ASCII (it travels in an HTTP header), not {char!r} at position "
                f"{position}: a machine's DNS name, punycode for others, would do"
            )
    return path_segment(value)


def name_characters(value: str, also: str = "") -> str:
    """``value`` of ASCII letters, digits, '.', '_', '-' (and the characters of ``also``) only,
    else a ValueError naming the first other character and its position (a regex's wording
    would say none of that)."""
    for position, char in enumerate(value):
        if not (char.isascii() and (char.isalnum() or char in "._-" + also)):
            allowed = ", ".join(repr(c) for c in "._-" + also)
            raise ValueError(
                f"{char!r} at position {position} is not allowed: use letters, digits, {allowed}"
            )
    return value


def component_name(value: str) -> str:
    if value[:1] in ("_", ".", "-"):
        raise ValueError("must start with a letter or a digit")
    return name_characters(value)


def inside_repository(value: str) -> str:
    """A relative path that stays inside the repository ('' keeps the default): the agent would
    refuse any other only when a job runs, long after the setting was made."""
    if value.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", value):
        raise ValueError("must be a path relative to the repository's root, not an absolute one")
    if ".." in re.split(r"[/\\]", value):
        raise ValueError("must stay inside the repository (no '..')")
    return one_line(value)


def commit_time(value: datetime) -> datetime:
    """``value`` in UTC (naive means UTC), between 1970 and a year from now."""
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    try:
        utc = value.astimezone(UTC)
    except OverflowError:
        raise ValueError(f"{value.isoformat()} is not a representable time in UTC") from None
    latest = datetime.now(UTC) + FUTURE_SLACK
    if not EARLIEST <= utc <= latest:
        raise ValueError(
            f"{utc.isoformat()} is not between {EARLIEST:%Y-%m-%d} and a year from now"
        )
    return utc


def parse_commit_time(text: str) -> datetime:
    """An ISO 8601 time (as a push event gives it) checked by `commit_time`."""
    try:
        return commit_time(datetime.fromisoformat(text))
    except ValueError as exc:
        raise ValueError(f"timestamp {text[:40]!r}: {exc}") from None


#: a component's name: letters, digits, '.', '_', '-', starting with a letter or digit
ComponentName = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(component_name)]
#: a revision's title: one path segment (a commit hash, a tag, "v1.2 rc1"...)
Title = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(path_segment)]
_COMMIT = re.compile(r"[A-Za-z0-9_][\w./@+-]*")


def git_commit(value: str) -> str:
    """``value`` if git can name a commit by it and will not read it as an option ("" passes:
    none given), else a ValueError that says what a commit may be."""
    if value and not _COMMIT.fullmatch(value):
        raise ValueError(
            "must be a commit hash, tag or branch: letters, digits and _ . / @ + -, not "
            "starting with . / @ + or - (git would read a leading '-' as an option)"
        )
    return value


#: the largest measurement taken (in magnitude): a trial's 1e308 made the statistics overflow
#: (NaN means, a change of 300 digits); no counter, time or size comes near
MEASURABLE = 1e30


def measurable(value: float) -> float:
    """``value`` if it is within ±`MEASURABLE`, else a ValueError saying so."""
    if abs(value) > MEASURABLE:
        raise ValueError(f"{value:g} is beyond ±{MEASURABLE:g}: no measurement is that large")
    return value


#: a measured sample: a number (never text such as "1.0"), finite, within ±`MEASURABLE`
Measure = Annotated[float, Field(strict=True, allow_inf_nan=False), AfterValidator(measurable)]
#: a commit as git names it (a hash, a tag, a branch); never starting with '-'
Commit = Annotated[str, Field(max_length=200), AfterValidator(git_commit)]
#: the same, where a performance host will check it out: never empty
RunCommit = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(git_commit)]
CommitTime = Annotated[datetime, AfterValidator(commit_time)]
#: a suite file's path inside a component's repository
SuitePath = Annotated[str, Field(max_length=500), AfterValidator(inside_repository)]


def whole_number_as_text(value: object) -> object:
    """A sort key given as a whole number (``12``, a CI build number) is its text (``"12"``,
    compared as a number: '9' < '10'); a trial's ``"sort_key": 12`` was refused. Any other
    number (``1.5``, NaN) is refused in words: "a valid string" did not say what would do."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    if isinstance(value, float) and math.isinf(value):  # a trial's 1e400 was said to be "inf"
        raise ValueError("a number too large to read as a JSON number: give it as text")
    if isinstance(value, float):
        raise ValueError(f"must be text or a whole number, not {value!r}")
    return value


#: a sort key of 10 or 11 digits reads as a Unix time in seconds (2001 to 5138): what `redline
#: ci report` sends by default; no build number comes near a billion
_UNIX_TIME = re.compile(r"[1-9][0-9]{9,10}")
#: a key of 10 digits that is a date and hour, or a date, hour and minute of a two-digit year,
#: as some CI systems stamp builds: a key in the order of time, not a Unix time
_DATED = ("%Y%m%d%H", "%y%m%d%H%M")


def _dated(value: str) -> bool:
    for layout in _DATED:
        try:
            datetime.strptime(value, layout)
        except ValueError:
            continue
        return True
    return False


def not_far_ahead(value: str) -> str:
    """``value`` unless it reads as a Unix time (`_UNIX_TIME`), not as a date (`_DATED`), more
    than a year from now: a trial's ci token reported a commit at 4102444800 (2100), which
    sorted above every revision reported after it, so the overview showed it, failed, as the
    newest for good."""
    if _UNIX_TIME.fullmatch(value) and not _dated(value):
        when = datetime.fromtimestamp(int(value), UTC)
        try:
            commit_time(when)  # the bounds of a commit's time
        except ValueError:
            raise ValueError(
                f"{value} reads as a Unix time, {when:%Y-%m-%d}, more than a year from now: it "
                "would sort above every revision reported after it (give the commit's time)"
            ) from None
    return value


#: what orders a component's revisions: text, or a whole number taken as its text
SortKey = Annotated[
    str,
    Field(min_length=1, max_length=200),  # before the validator: "200 characters", not "items"
    BeforeValidator(whole_number_as_text),
    AfterValidator(one_line),
    AfterValidator(not_far_ahead),
]


def git_branch(value: str) -> str:
    """``value`` as `printable`, and not starting with '-' (git refuses such a branch, and
    would read it as an option), else a ValueError saying so."""
    if value.startswith("-"):
        raise ValueError("must not start with '-': git would read it as an option")
    return printable(value)


#: a git branch, as a component's default or a revision's ('' where none is given)
Branch = Annotated[str, Field(max_length=200), AfterValidator(git_branch)]

#: the least length of a component's own webhook secret: the forge signs with it, and a short
#: one is guessed (a trial set "x")
SECRET_LENGTH = 16


def strong_secret(value: str) -> str:
    """``value`` when empty (no secret of its own) or of `SECRET_LENGTH` characters or more."""
    if value and len(value) < SECRET_LENGTH:
        raise ValueError(
            f"must be at least {SECRET_LENGTH} characters (python3 -c 'import secrets; "
            "print(secrets.token_urlsafe(24))' makes one), or '' for none of its own"
        )
    return value


#: a component's own webhook secret
WebhookSecret = Annotated[str, Field(max_length=200), AfterValidator(strong_secret)]
#: a host's label, as an agent's and a component's settings give it
Word = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(printable)]
#: a performance host's name ('' where an import does not say)
HostName = Annotated[str, Field(max_length=200), AfterValidator(host_name)]
#: a name shown in one line (a process, a counter, a parameter, a label), spaces allowed
Line = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(one_line)]
#: a stored row's id, as a body names it: a number past what the database holds is refused by
#: name, not as "a value in the request cannot be stored: integer out of range"
StoredId = Annotated[int, Field(ge=1, le=2**31 - 1)]
#: a component's description, shown in one line of the home page's table
Description = Annotated[str, Field(max_length=2000), AfterValidator(one_line)]
#: a test case's or phase's name, as the SDK allows it (`redline.testing.cases`)
TestName = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(name_characters)]


def param_value(value: Any) -> Any:
    """A parameter's value as an import gives it: text of one line, a number, true or false; a
    NaN was stored and then shown as None, nan and NaN on three pages, and a line break in a
    value broke every label that named its series."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int | float):
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"must be a finite number, not {value!r}")
        if abs(value) > MEASURABLE:  # a 400-digit one made the execution's page a 500
            raise ValueError(f"must be within ±{MEASURABLE:g}")
        return value
    if isinstance(value, str):
        if len(value) > 200:
            raise ValueError("must be at most 200 characters")
        return one_line(value)
    raise ValueError(f"must be text, a number, true or false, not {type(value).__name__}")


#: one parameter's value in an import
ParamValue = Annotated[Any, AfterValidator(param_value)]
