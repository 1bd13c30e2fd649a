"""Servers outside GeoCon that must answer in time: a Rerun viewer (``geocon view --connect``) and a
Ray cluster's head (``geocon bench --ray-address``) both speak gRPC, that is HTTP/2.

A port that accepts a connection and then says nothing (a process that is stopped, a proxy that
never forwards, any server of another protocol that waits for its client to speak first) passes a
plain ``connect``; the client libraries then wait for ever (Rerun) or for minutes (Ray).
:func:`http2_answer` asks the one question every HTTP/2 server answers at once: it sends the
connection preface and waits, within a time bound, for the server's first frame, which must be its
``SETTINGS`` (RFC 9113, section 3.4).
"""

from __future__ import annotations

import socket
import ssl
import threading
import time

__all__ = ["HTTP2_PREFACE", "http2_answer", "resolve"]

HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes.fromhex("000000040000000000")
"""The client connection preface of HTTP/2 followed by an empty ``SETTINGS`` frame."""
_SETTINGS = 0x4
"""The frame type of ``SETTINGS``, the first frame an HTTP/2 server sends."""


def _left(deadline: float) -> float:
    left = deadline - time.monotonic()
    if left <= 0:
        raise TimeoutError
    return left


def resolve(host: str, port: int, timeout_s: float) -> list[tuple[int, tuple]] | str:
    """(family, socket address) of every IPv4/IPv6 address of ``host``, looked up in a thread of
    its own and waited for at most ``timeout_s`` seconds (a resolver that hangs must not hang the
    command); else why not, in words."""
    found: list = []

    def lookup() -> None:
        try:
            found.append(socket.getaddrinfo(host, port, type=socket.SOCK_STREAM))
        except (OSError, UnicodeError) as exc:
            found.append(getattr(exc, "strerror", None) or str(exc))

    thread = threading.Thread(target=lookup, name="geocon-resolve", daemon=True)
    thread.start()
    thread.join(timeout_s)
    if not found:
        return f"{host} did not resolve within {timeout_s:g} s"
    if isinstance(found[0], str):
        return found[0]
    addrs = [(fam, addr) for fam, _, _, _, addr in found[0] if fam in (socket.AF_INET, socket.AF_INET6)]
    return list(dict.fromkeys(addrs)) or f"{host} has no IPv4 or IPv6 address"


def http2_answer(family: int, sockaddr: tuple, timeout_s: float, *, tls: bool = False, host: str = "") -> str | None:
    """None when the server at ``sockaddr`` (of address ``family``) accepts a connection and
    answers the HTTP/2 preface with its ``SETTINGS`` frame, all within ``timeout_s`` seconds (over
    TLS with ALPN ``h2`` when ``tls``, ``host`` naming it; its certificate is the client's to
    check); else why not, in a few words: ``"connection refused"``, ``"no answer within 5 s"``,
    ``"it answers, but not as an HTTP/2 (gRPC) server"``, ``"it closed the connection"`` or the
    system's reason."""
    deadline = time.monotonic() + timeout_s
    try:
        with socket.socket(family, socket.SOCK_STREAM) as raw:
            raw.settimeout(_left(deadline))
            raw.connect(sockaddr)
            sock: socket.socket = raw
            if tls:
                context = ssl.create_default_context()
                context.check_hostname = False
                context.verify_mode = ssl.CERT_NONE
                context.set_alpn_protocols(["h2"])
                raw.settimeout(_left(deadline))
                sock = context.wrap_socket(raw, server_hostname=host or None)
            sock.settimeout(_left(deadline))
            sock.sendall(HTTP2_PREFACE)
            head = b""
            while len(head) < 9:
                sock.settimeout(_left(deadline))
                chunk = sock.recv(9 - len(head))
                if not chunk:
                    return "it closed the connection"
                head += chunk
    except ConnectionRefusedError:
        return "connection refused"
    except (TimeoutError, socket.timeout):
        return f"no answer within {timeout_s:g} s"
    except ssl.SSLError as exc:
        return f"no TLS connection ({exc.reason or exc})"
    except OSError as exc:
        return (exc.strerror or str(exc) or type(exc).__name__).lower()
    return None if head[3] == _SETTINGS else "it answers, but not as an HTTP/2 (gRPC) server"
