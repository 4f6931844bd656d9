"""The websocket protocol ``contextweb serve`` runs: uvicorn's default one plus a way to reset a connection.

uvicorn (0.54) picks its sans-I/O ``websockets`` protocol when the ``websockets``
package is installed; ``contextweb serve`` names this subclass instead so that
the choice does not depend on what else is installed. Its sends wait while the
transport's write buffer is above the high-water mark, and its ``close`` waits
for that buffer to drain: a client that stopped reading holds its connection,
its buffers and a shutdown forever. ASGI has no message for dropping a
connection, so this protocol offers one as a scope extension (docs/stream.md,
"Slow clients"): ``scope["extensions"][RESET_EXTENSION]["reset"]()``.
"""

from __future__ import annotations

import contextlib
import fcntl
import socket
import struct
import termios

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

#: Scope extension of :class:`ResettableWebSocketProtocol`; absent under other servers (and the TestClient).
RESET_EXTENSION = "contextweb.websocket.reset"
#: How long a close handshake may take before the connection is reset. A client that reads answers
#: in milliseconds; a close frame stuck behind a full socket would never get through.
CLOSE_HANDSHAKE_SECONDS = 1.0


class ResettableWebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's websocket protocol whose app can reset the TCP connection."""

    async def run_asgi(self) -> None:
        self.scope["extensions"][RESET_EXTENSION] = {"reset": self.reset}
        await super().run_asgi()

    def shutdown(self) -> None:
        """uvicorn's (close with 1012), then a reset if the connection is still open after the handshake's time.

        uvicorn's shutdown waits for every connection to end, and without a deadline
        (``timeout_graceful_shutdown`` is unset) one client that does not read would hold it forever.
        """
        super().shutdown()
        self.loop.call_later(CLOSE_HANDSHAKE_SECONDS, self.reset)

    def keepalive_timeout(self) -> None:
        """uvicorn's (close with 1011 when no pong came), and tell the app, which uvicorn does not.

        Otherwise the app's next send fails with a RuntimeError in the log, and a connection whose
        buffer never drains stays open; told, the stream ends and resets it. When the kernel still
        holds data the client has not taken, the close is a reset at once (:meth:`_close_with_reset`).
        """
        failing = not (self.close_sent or self.transport.is_closing())
        if failing and self._kernel_holds_unsent_data():
            # The close frame would wait behind data the client does not take, and once uvicorn's
            # transport has nothing left to write it closes the socket at once: the kernel then kept
            # the orphaned socket, its buffers and the FIN behind a closed window for over a minute.
            self._close_with_reset()
        super().keepalive_timeout()
        if failing:
            self.queue.put_nowait({"type": "websocket.disconnect", "code": 1011, "reason": "keepalive ping timeout"})

    def reset(self) -> None:
        """Drop the connection now, buffered data and all; nothing once it is gone.

        ``SO_LINGER`` 0 makes the kernel discard its send buffer too and answer with
        an RST, instead of keeping an orphaned socket that retries a full window;
        ``abort`` discards the transport's buffer and runs ``connection_lost``, which
        tells the app ``websocket.disconnect`` and unblocks any waiting send.
        """
        if self.disconnected:
            return
        self._close_with_reset()
        self.transport.abort()

    def _close_with_reset(self) -> None:
        """``SO_LINGER`` 0: closing the socket, whenever it happens, sends an RST and drops the kernel's buffers."""
        sock = self.transport.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):  # not a TCP socket, or already shut down: abort is enough
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))

    def _kernel_holds_unsent_data(self) -> bool:
        """Whether the socket's kernel send queue still holds bytes the client has not acknowledged
        (Linux's ``TIOCOUTQ``; False where it cannot be read)."""
        sock = self.transport.get_extra_info("socket")
        request = getattr(termios, "TIOCOUTQ", None)
        if sock is None or request is None:
            return False
        try:
            queued = fcntl.ioctl(sock.fileno(), request, struct.pack("i", 0))
        except OSError:
            return False
        return struct.unpack("i", queued)[0] > 0
