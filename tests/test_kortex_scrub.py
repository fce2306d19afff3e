"""The Kortex password never leaves the adapter: not literally, and not in any escaped form a vendor
library may echo it in (repr, bytes repr, JSON, URL and form encoding, protobuf text format, UTF-8
octal escapes), for >= 100 hostile passwords (quotes, backslashes, non-ASCII, ``@ : % + /``,
newlines, tabs, control characters). The echoes are made with the real libraries (``json``,
``urllib.parse``, ``google.protobuf.text_format``), independently of :func:`ahrm_stack.hardware.kortex.scrub`.
"""

from __future__ import annotations

import json
import logging
import random
import types
import urllib.parse

import pytest
from google.protobuf import text_format, wrappers_pb2

from fake_kortex_api.rig import fake_api, options, standin_control_config, standin_frame, standin_reply
from ahrm_stack.hardware.kortex import Credentials, KortexArm, scrub, secret_variants
from ahrm_stack.hardware.protocol import HardwareError

HOSTILE = "'\"\\@:%+/?#&= \n\t\r\x00\x7féüß密码😀\u0301*$`{}<>;|"
SAFE = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_."


def _hostile_passwords(count: int = 120, seed: int = 17) -> list[str]:
    """Hand-picked nasties, then seeded random mixes of hostile and plain characters (8-20 long,
    each with at least two hostile characters)."""
    passwords = ["p@ss:w0rd%", "it's\"quoted\"", "back\\slash\\\\", "new\nline\r\n", "tab\tbed\t",
                 "ünïcødé-密码", "emoji😀pass", "%41%42%43", "a+b c/d?e", "\\x41\\u0042",
                 "\\303\\251oct", "json\\\"esc", "'\"'\"'\"", "null\x00byte", "del\x7fchar",
                 "combining é", "user:pass@host", "100%+ sure", "*** stars ***", "${HOME}`id`"]
    rng = random.Random(seed)
    while len(passwords) < count:
        length = rng.randint(8, 20)
        chars = [rng.choice(HOSTILE if rng.random() < 0.4 else SAFE) for _ in range(length)]
        chars[rng.randrange(length)] = rng.choice(HOSTILE)
        chars[rng.randrange(length)] = rng.choice(HOSTILE)
        passwords.append("".join(chars))
    return passwords


PASSWORDS = _hostile_passwords()


def _lower_hex(text: str) -> str:
    import re
    return re.sub(r"%[0-9A-F]{2}", lambda m: m.group().lower(), text)


#: How a vendor library may echo the login request into an exception message, each built with the
#: real library that writes that format.
ECHOES = {
    "literal": lambda pw: RuntimeError(f"login refused for admin/{pw}"),
    "repr of the request": lambda pw: RuntimeError(
        f"CreateSession({ {'username': 'admin', 'password': pw}!r})"),
    "exception args": lambda pw: RuntimeError("session refused", pw),
    "KeyError": lambda pw: KeyError(pw),
    "ascii": lambda pw: RuntimeError(f"bad password {pw!a}"),
    "repr of a repr": lambda pw: RuntimeError(repr(RuntimeError(repr(pw)))),
    "json": lambda pw: ValueError(json.dumps({"username": "admin", "password": pw})),
    "json utf-8": lambda pw: ValueError(json.dumps({"password": pw}, ensure_ascii=False)),
    "json in json": lambda pw: ValueError(json.dumps(json.dumps({"password": pw}))),
    "url userinfo": lambda pw: ConnectionError(
        f"tcp://admin:{urllib.parse.quote(pw, safe='')}@192.0.2.10:10000 unreachable"),
    "url path": lambda pw: RuntimeError(f"GET /login/{urllib.parse.quote(pw)} 401"),
    "form (quote_plus)": lambda pw: RuntimeError(
        "POST /login " + urllib.parse.urlencode({"user": "admin", "password": pw})),
    "url lowercase hex": lambda pw: RuntimeError(
        "uri " + _lower_hex(urllib.parse.quote(pw, safe=""))),
    "protobuf text": lambda pw: RuntimeError(
        text_format.MessageToString(wrappers_pb2.StringValue(value=pw))),
    "protobuf str()": lambda pw: RuntimeError(str(wrappers_pb2.StringValue(value=pw))),
    "protobuf octal utf-8": lambda pw: RuntimeError(
        str(wrappers_pb2.BytesValue(value=pw.encode("utf-8")))),
    "bytes repr": lambda pw: RuntimeError(f"payload {pw.encode('utf-8')!r}"),
}


def _leak_forms(pw: str) -> set[str]:
    """Independent renderings of ``pw`` whose presence in any output is a leak."""
    forms = {pw, repr(pw)[1:-1], ascii(pw)[1:-1], json.dumps(pw)[1:-1],
             json.dumps(pw, ensure_ascii=False)[1:-1], urllib.parse.quote(pw, safe=""),
             urllib.parse.quote(pw), urllib.parse.quote_plus(pw),
             _lower_hex(urllib.parse.quote(pw, safe="")), repr(pw.encode("utf-8"))[2:-1],
             text_format.MessageToString(wrappers_pb2.StringValue(value=pw)).strip()[8:-1],
             str(wrappers_pb2.BytesValue(value=pw.encode("utf-8"))).strip()[8:-1],
             repr(repr(pw))[1:-1], json.dumps(json.dumps(pw))[1:-1]}
    return {f for f in forms if f}


def _leaks(pw: str, texts) -> list[str]:
    forms = _leak_forms(pw)
    return [text for text in texts for form in forms if form in text]


def test_the_hostile_passwords_are_hostile():
    assert len(PASSWORDS) >= 100 and len(set(PASSWORDS)) == len(PASSWORDS)
    for char in "'\"\\@:%\n":
        assert sum(char in pw for pw in PASSWORDS) >= 5, char
    assert sum(any(ord(c) > 127 for c in pw) for pw in PASSWORDS) >= 20
    # Every echo differs from the literal for most passwords: the literal replace alone leaks.
    naive = sum(bool(_leaks(pw, [str(echo(pw)).replace(pw, "***")]))
                for pw in PASSWORDS for echo in ECHOES.values())
    assert naive > len(PASSWORDS)


@pytest.mark.parametrize("name", list(ECHOES))
def test_scrub_removes_every_echo(name):
    echo = ECHOES[name]
    for pw in PASSWORDS:
        text = f"{type(echo(pw)).__name__}: {echo(pw)}"
        scrubbed = scrub(text, [pw])
        assert not _leaks(pw, [scrubbed]), (name, pw, scrubbed)
        assert "***" in scrubbed


def test_scrub_leaves_text_without_the_secret_alone():
    assert scrub("connection refused by 192.0.2.10:10000", ["hunter2'\"@"]) == \
        "connection refused by 192.0.2.10:10000"
    assert scrub("anything", []) == "anything" and scrub("anything", [""]) == "anything"
    assert "p%40ss" in secret_variants("p@ss") and "p\\\\@" not in secret_variants("p@ss")



class SendOptions:
    """kortex_api.RouterClient.RouterClientSendOptions: the vendor default timeout is 10 s."""

    def __init__(self):
        self.andForget, self.delay_ms, self.timeout_ms = False, 0, 10000

def _api(fail_session=None, fail_feedback=None, healthy_frames: int = 1) -> dict:
    class Transport:
        def connect(self, address, port):
            pass

        def disconnect(self):
            pass

    class Session:
        def __init__(self, router):
            pass

        def CreateSession(self, info, **options):
            if fail_session is not None:
                raise fail_session

        def CloseSession(self, **options):
            pass

    class Info:
        pass

    class Base:
        def __init__(self, router):
            pass

        def __getattr__(self, name):
            return lambda *args, **options: standin_reply(name, 6)

    class Cyclic:
        calls = 0

        def __init__(self, router):
            pass

        def RefreshFeedback(self, **options):
            Cyclic.calls += 1
            if fail_feedback is not None and Cyclic.calls > healthy_frames:
                raise fail_feedback
            return standin_frame(6)

    return {"TCPTransport": types.SimpleNamespace(TCPTransport=Transport),
            "RouterClient": types.SimpleNamespace(RouterClient=lambda t, cb: object(),
                                                RouterClientSendOptions=SendOptions),
            "SessionManager": types.SimpleNamespace(SessionManager=Session),
            "BaseClientRpc": types.SimpleNamespace(BaseClient=Base),
            "BaseCyclicClientRpc": types.SimpleNamespace(BaseCyclicClient=Cyclic),
            "Session_pb2": types.SimpleNamespace(CreateSessionInfo=Info),
            "Base_pb2": types.SimpleNamespace(ServoingModeInformation=Info, SINGLE_LEVEL_SERVOING=2,
                                              LOW_LEVEL_SERVOING=3),
            "Common_pb2": fake_api()["Common_pb2"], **standin_control_config()}


def test_no_password_reaches_an_exception_or_the_log(task_config, caplog):
    """Every hostile password x every echo, through the adapter's three error paths (a refused
    login; the first feedback failing inside connect; a failing call once connected): 0 leaks in
    the raised error (str, repr, args) and in every log record."""
    from ahrm_stack.env.task import PushOffTask

    robot = PushOffTask(task_config).robot
    cases = leaks = 0
    for pw in PASSWORDS:
        for name, echo in ECHOES.items():
            for path in ("login", "first frame", "call"):
                caplog.clear()
                credentials = Credentials("admin", pw)
                api = (_api(fail_session=echo(pw)) if path == "login" else
                       _api(fail_feedback=echo(pw), healthy_frames=int(path == "call")))
                arm = KortexArm(robot, "192.0.2.10", credentials, options(), api=api)
                with caplog.at_level(logging.DEBUG), pytest.raises(HardwareError) as error:
                    arm.connect()
                    arm.refresh_feedback()
                texts = [str(error.value), repr(error.value), *map(str, error.value.args),
                         *(r.getMessage() for r in caplog.records)]
                assert error.value.__cause__ is None and error.value.__context__ is None
                cases += 1
                assert path == "call" or not arm.is_connected  # a failed connect closes up
                found = _leaks(pw, texts)
                leaks += bool(found)
                assert not found, (name, path, pw, found)
                arm.disconnect()  # the "call" path stays connected: close it (and its watchdog)
    assert cases == len(PASSWORDS) * len(ECHOES) * 3 and leaks == 0
