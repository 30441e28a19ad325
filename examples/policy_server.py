"""openpi's policy-server protocol for any Python policy, as openpi's `WebsocketPolicyServer`
serves it: on connecting, the client gets `policy.metadata()`; then every binary message it
sends (msgpack-numpy, `openpi_client.msgpack_numpy`) is an observation answered with
`policy.infer(observation)`, e.g. `{"actions": float32 (H, 7)}`. An exception is sent back as
text (the traceback) and the connection closes; `surgvla eval` fails that trial with the text
and reconnects for the next.

    asyncio.run(serve(policy, "127.0.0.1", 8000))   # port 0 picks a free one, printed

Needs `openpi-client` and `websockets` (examples/requirements-serve.txt).
"""

import traceback

import websockets.asyncio.server
import websockets.frames
from openpi_client import msgpack_numpy


async def serve(policy, host: str, port: int, name: str = "policy") -> None:
    """Serves `policy` (with `metadata() -> dict` and `infer(dict) -> dict`) until cancelled;
    prints `serving NAME on ws://HOST:PORT` once listening."""

    async def handler(websocket):
        packer = msgpack_numpy.Packer()
        await websocket.send(packer.pack(policy.metadata()))
        while True:
            try:
                observation = msgpack_numpy.unpackb(await websocket.recv())
                await websocket.send(packer.pack(policy.infer(observation)))
            except websockets.ConnectionClosed:
                break
            except Exception:
                await websocket.send(traceback.format_exc())
                await websocket.close(
                    code=websockets.frames.CloseCode.INTERNAL_ERROR,
                    reason="Internal server error. Traceback included in previous frame.",
                )
                raise

    async with websockets.asyncio.server.serve(
        handler, host, port, compression=None, max_size=None
    ) as server:
        bound = server.sockets[0].getsockname()[1]
        print(f"serving {name} on ws://{host}:{bound}", flush=True)
        await server.serve_forever()
