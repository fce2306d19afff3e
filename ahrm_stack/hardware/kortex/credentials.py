"""Kortex credentials: read from environment variables or a file outside the repository, never
logged, never in an error message (:func:`scrub` removes every echo of a secret from a text)."""

from __future__ import annotations

import dataclasses
import functools
import html
import json
import os
import re
import urllib.parse
from pathlib import Path
from typing import Mapping, Sequence

from ahrm_stack.hardware.protocol import HardwareError

REPOSITORY_ROOT = Path(__file__).resolve().parents[3]
USERNAME_ENV = "KORTEX_USERNAME"
PASSWORD_ENV = "KORTEX_PASSWORD"
CREDENTIALS_FILE_ENV = "KORTEX_CREDENTIALS_FILE"


class CredentialsError(HardwareError):
    """Credentials are missing or stored somewhere they must not be; never contains a secret."""


@dataclasses.dataclass(frozen=True)
class Credentials:
    """A Kortex login. ``repr`` and ``str`` never show the password."""

    username: str
    password: str = dataclasses.field(repr=False)

    def __repr__(self) -> str:
        return f"Credentials(username={self.username!r}, password='***')"

    __str__ = __repr__


def _c_escape(text: str, *, octal_utf8: bool) -> str:
    """C-style escaping as protobuf's text format writes a string (``CEscape``): ``\\n \\r \\t``,
    backslash-escaped quotes and backslash, other control bytes in octal; non-ASCII kept as is, or
    (``octal_utf8``) each UTF-8 byte as a 3-digit octal escape (``é`` -> ``\\303\\251``)."""
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t", '"': '\\"', "'": "\\'",
             "\\": "\\\\"}
    out = []
    for char in text:
        if char in named:
            out.append(named[char])
        elif ord(char) < 0x20 or ord(char) == 0x7F or (octal_utf8 and ord(char) > 0x7F):
            out.extend(f"\\{byte:03o}" for byte in char.encode("utf-8", "surrogatepass"))
        else:
            out.append(char)
    return "".join(out)


def _inner(quoted: str) -> str:
    """A quoted literal without its quotes (and a ``b`` prefix): ``'a\\'b'`` -> ``a\\'b``."""
    return quoted[2:-1] if quoted[:1] == "b" else quoted[1:-1]


#: The ways a library may echo a string into an exception or a log line, each as text -> text.
#: :func:`secret_variants` composes them twice (an escaped echo inside an escaped echo, e.g. the
#: repr of an exception whose message holds a repr).
_ENCODINGS = (
    lambda s: _inner(repr(s)),  # Python repr: \\ \' \n, non-printable as \x.. \u....
    lambda s: _inner(ascii(s)),  # repr with non-ASCII escaped
    lambda s: s.encode("unicode_escape").decode("ascii"),  # like ascii(), quotes unescaped
    lambda s: _inner(repr(s.encode("utf-8", "surrogatepass"))),  # bytes repr: \xc3\xa9
    lambda s: _inner(json.dumps(s)),  # JSON, \u00e9 and surrogate pairs
    lambda s: _inner(json.dumps(s, ensure_ascii=False)),  # JSON, non-ASCII kept
    lambda s: urllib.parse.quote(s, safe=""),  # URL encoding (userinfo, form values)
    lambda s: urllib.parse.quote(s),  # ... with '/' kept (quote's default)
    lambda s: urllib.parse.quote_plus(s),  # form encoding: ' ' -> '+'
    lambda s: urllib.parse.quote_plus(s, safe="/"),
    lambda s: _c_escape(s, octal_utf8=False),  # protobuf text format (as_utf8=True)
    lambda s: _c_escape(s, octal_utf8=True),  # protobuf text format, UTF-8 bytes in octal
    lambda s: html.escape(s),  # XML / HTML bodies
    lambda s: s.encode("utf-8", "surrogatepass").decode("latin-1"),  # UTF-8 read as Latin-1
)

_HEX_ESCAPE = re.compile(r"(%|\\x)([0-9a-fA-F]{2})|(\\u)([0-9a-fA-F]{4})|(\\U)([0-9a-fA-F]{8})")


def _hex_case(text: str, case) -> str:
    """``text`` with the digits of its hex escapes (``%2f``, ``\\xc3``, ``\\u00e9``) in ``case``."""
    def repl(match: re.Match) -> str:
        prefix, digits = next((match.group(i), match.group(i + 1)) for i in (1, 3, 5)
                              if match.group(i) is not None)
        return prefix + case(digits)
    return _HEX_ESCAPE.sub(repl, text)


def _encodings(text: str) -> set[str]:
    """``text`` under each of :data:`_ENCODINGS` (an encoding that cannot take it is skipped,
    e.g. URL encoding of a lone surrogate)."""
    out = set()
    for encode in _ENCODINGS:
        try:
            out.add(encode(text))
        except (UnicodeError, ValueError):
            pass
    return out


def secret_variants(secret: str) -> frozenset[str]:
    """``secret`` as every encoding of :data:`_ENCODINGS` may echo it: the literal, each encoding,
    each encoding of an encoding, and each with its hex escapes in upper and lower case."""
    variants = {secret}
    for _ in range(2):
        variants |= set().union(*(_encodings(v) for v in variants))
    variants |= {_hex_case(v, case) for v in variants for case in (str.upper, str.lower)}
    return frozenset(v for v in variants if v)


@functools.lru_cache(maxsize=8)
def _scrubber(secrets: tuple[str, ...]) -> re.Pattern | None:
    variants = set().union(*(secret_variants(s) for s in secrets if s))
    if not variants:
        return None
    # Longest first: at each position the longest echo wins, so no tail of one is left behind.
    return re.compile("|".join(re.escape(v) for v in sorted(variants, key=lambda v: (-len(v), v))))


def scrub(text: str, secrets: Sequence[str]) -> str:
    """``text`` with every echo of every non-empty secret replaced by ``***``: the literal and its
    escaped forms (repr, bytes repr, JSON, URL/form encoding, protobuf text format escapes in
    octal, HTML; see :func:`secret_variants`)."""
    pattern = _scrubber(tuple(secrets))
    if pattern is None:
        return text
    for _ in range(3):  # an echo may surface only once a longer overlapping one is gone
        scrubbed = pattern.sub("***", text)
        if scrubbed == text:
            break
        text = scrubbed
    return text


def load_credentials(file: str | Path | None = None, env: Mapping[str, str] | None = None,
                     repository_root: Path = REPOSITORY_ROOT) -> Credentials:
    """Credentials from ``file`` (or ``$KORTEX_CREDENTIALS_FILE``), else from
    ``$KORTEX_USERNAME`` / ``$KORTEX_PASSWORD``.

    The file holds two lines, ``username`` then ``password``, and must lie outside the repository
    (so it can never be committed). Errors name the file or variable, never a secret.
    """
    env = os.environ if env is None else env
    file = file if file is not None else env.get(CREDENTIALS_FILE_ENV)
    if file:
        path = Path(file).expanduser().resolve()
        root = Path(repository_root).resolve()
        if path == root or root in path.parents:
            raise CredentialsError(f"credentials file {path} is inside the repository ({root}); "
                                   "keep it outside so it is never committed")
        try:
            lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        except OSError as error:
            raise CredentialsError(f"cannot read credentials file {path}: {error.strerror}") from None
        if len(lines) != 2:
            raise CredentialsError(f"credentials file {path} must hold 2 non-empty lines "
                                   f"(username, password), found {len(lines)}")
        return Credentials(lines[0], lines[1])
    username, password = env.get(USERNAME_ENV), env.get(PASSWORD_ENV)
    if not username or not password:
        missing = USERNAME_ENV if not username else PASSWORD_ENV
        raise CredentialsError(f"no Kortex credentials: set {USERNAME_ENV} and {PASSWORD_ENV}, or "
                               f"{CREDENTIALS_FILE_ENV} / kortex.credentials_file to a file outside "
                               f"the repository ({missing} is missing)")
    return Credentials(username, password)

