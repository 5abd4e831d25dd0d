"""A lean load generator for the console's API: browsers' requests and event streams from one process.

The console's users are browsers on their own machines; on the bench they share the server's machine,
so every cycle the load generator spends is taken from the trainings it measures. This one runs all
clients as coroutines on one event loop (uvloop when installed), speaks HTTP/1.1 keep-alive over
asyncio streams and parses responses with ``httptools`` (the C parser uvicorn uses; in the console
extra). Event streams look only for ``iteration`` events (to time their delivery) and count the rest.

Runs until its standard input closes, then prints one JSON document: the latencies of
``GET /api/models`` (s), the slow ones (> 100 ms, with their start in s after the load began), the
iteration events' delivery delays (s, the worker's write time ``t`` to the moment read), the number
of errors and of events read, and this process's CPU seconds.

Usage: python bench/http_load.py --port PORT --token TOKEN [--clients 50] [--streams 20] [--think 3]
                                 [--model served-0 --model served-1]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
import time

import httptools


class Response:
    """One HTTP response fed to ``httptools``; ``on_chunk`` sees the body as it arrives."""

    def __init__(self, on_chunk=None):
        self.parser = httptools.HttpResponseParser(self)
        self.body = bytearray()
        self.complete = False
        self.on_chunk = on_chunk

    def on_body(self, chunk: bytes) -> None:
        if self.on_chunk is None:
            self.body += chunk
        else:
            self.on_chunk(chunk)

    def on_message_complete(self) -> None:
        self.complete = True


def request(path: str, port: int, token: str) -> bytes:
    return (f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nAuthorization: Bearer {token}\r\n"
            "Accept: */*\r\n\r\n").encode()


class Load:
    """Shared results of every client coroutine."""

    def __init__(self):
        self.latencies: list[float] = []
        self.slow: list[tuple[float, float]] = []
        self.deliveries: list[float] = []
        self.events = 0
        self.errors = 0
        self.started = time.perf_counter()
        self.stop = asyncio.Event()

    async def stopped_within(self, seconds: float) -> bool:
        """Wait ``seconds`` (none when 0) or until the load stops; whether it stopped."""
        if seconds > 0:
            try:
                await asyncio.wait_for(self.stop.wait(), seconds)
            except asyncio.TimeoutError:
                pass
        return self.stop.is_set()

    async def api_client(self, port: int, token: str, think: float) -> None:
        """One Models page: ``GET /api/models`` every ``think`` s on one keep-alive connection."""
        if await self.stopped_within(random.uniform(0, think)):  # pages opened at different moments
            return
        message = request("/api/models", port, token)
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        try:
            while not self.stop.is_set():
                t0 = time.perf_counter()
                response = Response()
                writer.write(message)
                while not response.complete:
                    data = await reader.read(65536)
                    if not data:
                        raise ConnectionError("the server closed the connection")
                    response.parser.feed_data(data)
                latency = time.perf_counter() - t0
                if response.parser.get_status_code() == 200:
                    self.latencies.append(latency)
                    if latency > 0.1:
                        self.slow.append((t0 - self.started, latency))
                else:
                    self.errors += 1
                await self.stopped_within(think)
        except (OSError, ConnectionError, httptools.HttpParserError):
            self.errors += 1
        finally:
            writer.close()

    async def stream_client(self, port: int, token: str, model: str) -> None:
        """One open training page: the model's server-sent events, timing each ``iteration`` event."""
        pending = bytearray()

        def on_chunk(chunk: bytes) -> None:
            pending.extend(chunk)
            while (end := pending.find(b"\n\n")) >= 0:
                event = bytes(pending[:end])
                del pending[:end + 2]
                self.events += 1
                if b"event: iteration\n" in event:
                    data = event[event.index(b"data: ") + 6:]
                    self.deliveries.append(time.time() - json.loads(data)["t"])

        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        response = Response(on_chunk)
        writer.write(request(f"/api/models/{model}/events", port, token))
        try:
            while not self.stop.is_set() and not response.complete:
                read = asyncio.ensure_future(reader.read(65536))
                stopped = asyncio.ensure_future(self.stop.wait())
                done, _ = await asyncio.wait({read, stopped}, return_when=asyncio.FIRST_COMPLETED)
                stopped.cancel()
                if read not in done:
                    read.cancel()
                    break
                data = read.result()
                if not data:
                    break
                response.parser.feed_data(data)
            if response.parser.get_status_code() != 200:
                self.errors += 1
        except (OSError, httptools.HttpParserError):
            self.errors += 1
        finally:
            writer.close()


async def run(args: argparse.Namespace) -> Load:
    load = Load()
    models = args.model or ["served-0"]
    tasks = [asyncio.ensure_future(load.api_client(args.port, args.token, args.think)) for _ in range(args.clients)]
    tasks += [asyncio.ensure_future(load.stream_client(args.port, args.token, models[i % len(models)]))
              for i in range(args.streams)]
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)  # until the bench closes our stdin
    load.stop.set()
    if tasks:
        await asyncio.wait(tasks, timeout=10)
    return load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--token", required=True)
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--streams", type=int, default=20)
    parser.add_argument("--think", type=float, default=3.0, help="s between one client's requests (0: none)")
    parser.add_argument("--model", action="append", help="the models whose events the streams read (repeatable)")
    args = parser.parse_args()
    try:
        from uvloop import run as run_loop
    except ImportError:
        run_loop = asyncio.run
    load = run_loop(run(args))
    json.dump({"latencies": load.latencies, "slow": load.slow, "deliveries": load.deliveries, "events": load.events,
               "errors": load.errors, "cpu": time.process_time()}, sys.stdout)


if __name__ == "__main__":
    main()
