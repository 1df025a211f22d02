"""Who may propose motion: the policy link's TLS, its bearer token and its subprotocol.

``[policy.tls]`` makes the link ``wss://``: the server's certificate must chain to the
manifest's CA bundle and carry the expected name; a client certificate is presented when the
manifest names one. ``[policy.auth]`` names where a bearer token is kept (a file readable by its
owner only, or an environment variable), never the token: a manifest is signed and journaled,
not secret. Speaking warden's protocol, the client offers the ``warden.v1`` websocket subprotocol
and talks only to a server that selects it, so a foreign server (or, on the reference server's
side, a foreign client) fails at connect time, before a frame of the protocol is exchanged.

Everything is read and checked while the manifest loads (:func:`link_security`), so a missing
file, a bad bundle or an unset variable exits 2 naming its key before any device starts. At
connect time :func:`why_refused` turns what went wrong into one line an operator can act on.
"""

from __future__ import annotations

import os
import ssl
import stat
from pathlib import Path

from websockets.exceptions import InvalidHandshake, InvalidMessage, InvalidStatus

from kernel.shell.link_credentials import SUBPROTOCOL, LinkSecurity, Token, subprotocols
from kernel.shell.link_settings import AuthSettings, PolicySettings, TlsSettings

MAX_TOKEN_BYTES = 4096


class SecurityError(ValueError):
    """A ``[policy.tls]`` or ``[policy.auth]`` key that cannot be used, with its key path."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key
        self.message = message


def check_shape(policy: PolicySettings) -> None:
    """What the tables must say, whatever machine reads them (no file is read): exactly one
    place for the token, a client certificate with its key.

    Raises:
        SecurityError: naming the key."""
    auth, tls = policy.auth, policy.tls
    if auth is not None and (auth.token_file is None) == (auth.token_env is None):
        raise SecurityError("auth", "name exactly one of token_file and token_env")
    if tls is not None and (tls.cert_file is None) != (tls.key_file is None):
        key = "tls.key_file" if tls.key_file is None else "tls.cert_file"
        raise SecurityError(key, "cert_file and key_file go together (the client certificate "
                                 "and its private key)")


def link_security(policy: PolicySettings, base: Path) -> LinkSecurity:
    """The link's TLS context and token, every file read now; relative paths from ``base``
    (the manifest's directory).

    Raises:
        SecurityError: naming the key (``tls.ca_file``, ``auth.token_env``, ...)."""
    check_shape(policy)
    tls = None if policy.tls is None else _client_context(policy.tls, base)
    token = None if policy.auth is None else _token(policy.auth, base)
    name = None if policy.tls is None else (policy.tls.server_name or policy.host)
    return LinkSecurity(tls=tls, server_name=name, token=token)


def _client_context(settings: TlsSettings, base: Path) -> ssl.SSLContext:
    context = ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_verify_locations(cafile=_file(settings.ca_file, base, "tls.ca_file"))
    except ssl.SSLError as error:
        raise SecurityError("tls.ca_file",
                            f"not a PEM certificate bundle ({error.reason})") from None
    if settings.cert_file is not None and settings.key_file is not None:
        cert = _file(settings.cert_file, base, "tls.cert_file")
        key = _private(_file(settings.key_file, base, "tls.key_file"), "tls.key_file")
        try:
            context.load_cert_chain(cert, key)
        except ssl.SSLError as error:
            raise SecurityError("tls.cert_file", f"the certificate and key do not load "
                                                 f"together ({error.reason})") from None
    return context


def _token(settings: AuthSettings, base: Path) -> Token:
    if settings.token_env is not None:
        text = os.environ.get(settings.token_env)
        if text is None or not text.strip():
            raise SecurityError("auth.token_env", f"the environment variable "
                                                  f"{settings.token_env} is not set or empty")
        return _checked(text.strip(), "auth.token_env")
    path = _private(_file(settings.token_file or "", base, "auth.token_file"),
                    "auth.token_file")
    try:
        raw = Path(path).read_bytes()[:MAX_TOKEN_BYTES + 1]
    except OSError as error:
        raise SecurityError("auth.token_file",
                            f"{path}: cannot be read ({error.strerror})") from None
    try:
        text = raw.decode("ascii").strip()
    except UnicodeDecodeError:
        raise SecurityError("auth.token_file", f"{path}: the token must be ASCII") from None
    return _checked(text, "auth.token_file")


def _checked(text: str, key: str) -> Token:
    """A token that fits in one HTTP header: visible ASCII, no spaces, bounded."""
    if not text:
        raise SecurityError(key, "the token is empty")
    if len(text) > MAX_TOKEN_BYTES:
        raise SecurityError(key, f"the token is longer than {MAX_TOKEN_BYTES} characters")
    if not all(33 <= ord(c) <= 126 for c in text):
        raise SecurityError(key, "the token must be one word of visible ASCII characters")
    return Token(text)


def _file(name: str, base: Path, key: str) -> str:
    path = Path(name) if Path(name).is_absolute() else base / name
    if not path.is_file():
        raise SecurityError(key, f"{path}: no such file")
    return str(path)


def _private(path: str, key: str) -> str:
    """A secret (a private key, a token) that others on the machine can read is refused, as
    ssh refuses such a key."""
    mode = os.stat(path).st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SecurityError(key, f"{path}: readable by others (mode {stat.S_IMODE(mode):o}); "
                                 f"chmod 600 it")
    return path


def why_refused(error: BaseException, tls: bool) -> str | None:
    """What an operator should read when connecting failed for a reason retrying will not
    mend (a certificate, a credential, a plain-text link to a TLS server, a foreign server),
    or None for a reason it may (nobody listening yet, a timeout). ``tls``: whether the
    link is ``wss://``."""
    error = _tls_cause(error)
    if isinstance(error, ssl.SSLCertVerificationError):
        return (f"TLS: the policy server's certificate was refused ({error.verify_message}); "
                f"check [policy.tls] ca_file and server_name")
    if isinstance(error, ssl.SSLError):
        return f"TLS: the handshake with the policy server failed ({error.reason or error})"
    if isinstance(error, InvalidStatus):
        status = error.response.status_code
        if status in (401, 403):
            return (f"the policy server refused this robot's credentials (HTTP {status}); "
                    f"check [policy.auth]")
        return f"the policy server refused the websocket handshake (HTTP {status})"
    if isinstance(error, InvalidMessage) and tls:
        return ("the policy server closed the connection during the handshake (does it "
                "require a client certificate? [policy.tls] cert_file and key_file)")
    if isinstance(error, InvalidMessage):
        return ("the policy server answered no websocket handshake (a TLS-only server spoken "
                "to without [policy.tls]?)")
    if isinstance(error, InvalidHandshake):
        return f"the websocket handshake failed ({error})"
    return None


def _tls_cause(error: BaseException) -> BaseException:
    """The TLS error behind a failed websocket handshake, if one is (a server that refuses
    the client's certificate says so in an alert the client reads only while waiting for
    the HTTP answer); else ``error`` itself."""
    cause: BaseException | None = error
    while cause is not None:
        if isinstance(cause, ssl.SSLError):
            return cause
        cause = cause.__cause__ or cause.__context__
    return error


__all__ = ["SUBPROTOCOL", "LinkSecurity", "SecurityError", "Token", "check_shape", "link_security",
           "subprotocols", "why_refused"]
