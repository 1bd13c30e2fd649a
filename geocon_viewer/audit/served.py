"""What the Viser apps (``geocon serve``, ``geocon teach``) share as served pages: where they are."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import viser

__all__ = ["ServedApp"]


class ServedApp:
    """A Viser app reachable at :attr:`url` (its ``server`` is a ``viser.ViserServer``)."""

    server: viser.ViserServer

    @property
    def host(self) -> str:
        return str(self.server.get_host())

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        """``http://HOST:PORT``, an IPv6 address in brackets (``http://[::1]:8080``)."""
        host = self.host
        return f"http://[{host}]:{self.port}" if ":" in host else f"http://{host}:{self.port}"
