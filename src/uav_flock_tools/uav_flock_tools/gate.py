"""The view's WebSocket port, open to both names of the Foxglove WebSocket protocol.

The foxglove-sdk server accepts only the subprotocol `foxglove.sdk.v1`; Lichtblick releases before their sdk.v1
support, and other tools, offer `foxglove.websocket.v1`, which is the same protocol under its former name. The
SDK's server therefore listens on a loopback port of its own, and this gate, on the port the user asked for,
accepts either name and relays each client's frames to it and back unchanged (`websockets`). A client that
offers neither is refused with HTTP 400 and a line that says why, where the SDK logged only "handshake failed".
"""
from __future__ import annotations

import asyncio
import threading
from typing import Any, Callable, Optional

SDK = 'foxglove.sdk.v1'
PROTOCOLS = (SDK, 'foxglove.websocket.v1')
START_S = 10.0  # for the gate's socket to be bound, or its error known


def start_server(said: Callable[[str], None], host: str = '127.0.0.1', port: int = 8765, **kwargs: Any) -> 'Served':
    """foxglove.start_server(**kwargs) behind a gate on host:port; RuntimeError if that port cannot be served
    (as the SDK's own start_server raises)."""
    import foxglove
    inner = foxglove.start_server(host='127.0.0.1', port=0, **kwargs)
    try:
        gate = Gate(host, port, inner.port, said)
    except RuntimeError:
        inner.stop()
        raise
    return Served(inner, gate)


class Served:
    """The SDK's server as the callers use it (broadcast_time, stop), with the gate's port as its port."""

    def __init__(self, inner: Any, gate: 'Gate') -> None:
        self.inner, self.gate = inner, gate

    @property
    def port(self) -> int:
        return self.gate.port

    def broadcast_time(self, ns: int) -> None:
        self.inner.broadcast_time(ns)

    def stop(self) -> None:
        self.gate.stop()
        self.inner.stop()


def offered(header: Optional[str]) -> list[str]:
    """The subprotocols of a Sec-WebSocket-Protocol header, in the client's order."""
    return [p.strip() for p in (header or '').split(',') if p.strip()]


class Gate:
    """A WebSocket server on its own thread's event loop, relaying each client to the SDK's server."""

    def __init__(self, host: str, port: int, upstream: int, said: Callable[[str], None]) -> None:
        self.upstream, self.said = upstream, said
        self.port = port
        self.loop = asyncio.new_event_loop()
        self.server: Any = None
        self.error: Optional[BaseException] = None
        bound = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(host, port, bound), name='view-gate', daemon=True)
        self.thread.start()
        if not bound.wait(START_S):
            raise RuntimeError(f'the view did not bind {host}:{port} within {START_S:.0f} s')
        if self.error is not None:
            raise RuntimeError(str(self.error)) from None

    def _run(self, host: str, port: int, bound: threading.Event) -> None:
        from websockets.asyncio.server import serve

        async def open_port() -> Any:
            return await serve(self._relay, host, port, subprotocols=list(PROTOCOLS), process_request=self._check,
                               max_size=None, ping_interval=None, compression=None)
        asyncio.set_event_loop(self.loop)
        try:
            self.server = self.loop.run_until_complete(open_port())
            self.port = int(self.server.sockets[0].getsockname()[1])
        except OSError as exc:  # the port is taken, or the host is not this machine's
            self.error = exc
            bound.set()
            return
        bound.set()
        self.loop.run_forever()

    def _check(self, connection: Any, request: Any) -> Any:
        """A WebSocket handshake that offers neither name is refused here, with the reason said and sent."""
        if request.headers.get('Upgrade', '').lower() != 'websocket':
            return None  # not a WebSocket handshake: websockets answers it (426)
        names = offered(request.headers.get('Sec-WebSocket-Protocol'))
        if set(names) & set(PROTOCOLS):
            return None
        why = (f'refused a client at {connection.remote_address[0]}: it offered '
               f'{", ".join(names) if names else "no subprotocol"}; the view speaks {" or ".join(PROTOCOLS)}')
        self.said(f'view: {why}')
        return connection.respond(400, why + '\n')

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed
        try:
            async with connect(f'ws://127.0.0.1:{self.upstream}', subprotocols=[SDK], max_size=None,
                               ping_interval=None, compression=None) as sdk:
                pumps = [asyncio.ensure_future(_pump(client, sdk)), asyncio.ensure_future(_pump(sdk, client))]
                _, pending = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
                for task in pending:
                    task.cancel()
        except (ConnectionClosed, OSError):
            pass

    def stop(self) -> None:
        if self.server is not None and self.loop.is_running():
            async def close() -> None:
                self.server.close()
                await self.server.wait_closed()
            asyncio.run_coroutine_threadsafe(close(), self.loop).result(timeout=START_S)
            self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=START_S)


async def _pump(source: Any, sink: Any) -> None:
    from websockets.exceptions import ConnectionClosed
    try:
        async for message in source:
            await sink.send(message)
    except ConnectionClosed:
        pass
