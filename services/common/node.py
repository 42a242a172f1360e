"""The thin shell around every service's core: Zenoh in, validated messages to handlers, out.

A ``Node`` owns the session, declares ``alive/<service>/<instance>`` and answers
``metrics/<service>/<instance>``. Every input is decoded and validated before a handler sees it;
what fails is dropped, counted per reason and logged once per reason — a bad message never stops
a service, nor does a handler that raises. ``spin()`` blocks until SIGINT/SIGTERM or ``stop()``.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

import zenoh

from schemas.base import Message
from schemas.codec import CodecError, decode, encode, encode_fields
from schemas.keys import Keys, check_chunk
from schemas.runtime import QueryError
from services.common.config import ServiceSettings
from services.common.metrics import Metrics
from services.common.realtime import ordinary, os_thread_name
from services.common.transport import open_session, publisher_options

M = TypeVar("M", bound=Message)

#: samples a latest-only input keeps waiting: the newest valid one of them is handled
LATEST_RING = 16
#: how often a spinning main thread wakes to act on a signal (``Node.spin``)
SPIN_S = 0.1


class RemoteError(RuntimeError):
    """A queryable answered with an error."""


class Output:
    """A declared publisher that encodes messages and counts them."""

    def __init__(self, node: Node, key: str, **options: Any) -> None:
        self.key = key
        self._node = node
        self._publisher = node.session.declare_publisher(
            key, **{**publisher_options(key), **options}
        )

    def put(self, message: Message) -> None:
        self.put_raw(encode(message))

    def put_fields(self, cls: type[Message], **fields: Any) -> None:
        """Publish a ``cls`` message from its fields without building it
        (``codec.encode_fields``: the 1 kHz streams; receivers validate)."""
        self.put_raw(encode_fields(cls, **fields))

    def put_raw(self, payload: bytes) -> None:
        """Publish already encoded bytes (a replay)."""
        self._publisher.put(payload)
        self._node.metrics.count_out(self.key)

    @property
    def matched(self) -> bool:
        """Whether any subscriber currently matches this key."""
        return self._publisher.matching_status.matching  # a MatchingStatus, not a bool

    def undeclare(self) -> None:
        self._publisher.undeclare()


class Subscription:
    """A declared input (``Node.subscribe``, ``Node.inbox``) that can go before the node does:
    ``undeclare()`` ends it (a queued or latest-only input's thread ends with it)."""

    def __init__(self, node: Node, subscriber: Any) -> None:
        self._node, self._subscriber = node, subscriber

    def undeclare(self) -> None:
        if self._subscriber in self._node._subscribers:
            self._node._subscribers.remove(self._subscriber)
            self._subscriber.undeclare()


class Inbox(Subscription, Generic[M]):
    """A polled input (``Node.inbox``): no callback and no thread; the service's own loop takes
    what came, validated and counted like a subscription's samples."""

    def __init__(self, node: Node, subscriber: Any, message_type: type[M], size: int) -> None:
        super().__init__(node, subscriber)
        self._type, self._size = message_type, size
        self._key = str(subscriber.key_expr)

    def _waiting(self) -> list[zenoh.Sample]:
        waiting: list[zenoh.Sample] = []
        try:
            while (sample := self._subscriber.handler.try_recv()) is not None:
                waiting.append(sample)
        except zenoh.ZError:  # closed: the node is stopping
            pass
        except RuntimeError:
            # "Already mutably borrowed": close() undeclared the subscriber on another thread
            # while this one read it (the sim's physics loop crashed so at the end of a run)
            if not self._node.stopping:
                raise
        return waiting

    def _valid(self, sample: zenoh.Sample) -> M | None:
        key = str(sample.key_expr)
        self._node.metrics.count_in(key)
        return self._node.decode(key, sample.payload.to_bytes(), self._type)

    def take(self) -> list[M]:
        """The valid messages that came since the last call, oldest first (a full ring is
        counted as ``inbox_full``: older ones may have been overwritten)."""
        waiting = self._waiting()
        if len(waiting) >= self._size:
            detail = f"{len(waiting)} samples waited: the loop took them too late"
            self._node.drop("inbox_full", self._key, detail)
        return [m for s in waiting if (m := self._valid(s)) is not None]

    def newest(self) -> M | None:
        """The newest valid message of those that came since the last call (None: none did),
        for an input read only when it is needed (a pose when a plan starts): the waiting
        samples are decoded newest first until one is valid, so garbage cannot hide a good
        one; the older ones are not decoded at all (counted in, and as ``unread``)."""
        waiting = self._waiting()
        for k, sample in enumerate(reversed(waiting)):
            if (message := self._valid(sample)) is not None:
                older = len(waiting) - k - 1
                if older:
                    self._node.metrics.count_in(self._key, older)
                    self._node.metrics.drop_n("unread", older)
                return message
        return None


class Node:
    """A service's connection to the system. Use as a context manager, or call ``close()``."""

    def __init__(
        self,
        service: str,
        settings: ServiceSettings,
        session: zenoh.Session | None = None,
        *,
        announce: bool = True,
    ) -> None:
        """With ``announce=False`` the liveliness token waits for ``announce()``: declare it
        once every input and queryable exists, so that 'alive' means 'ready'."""
        self.service = check_chunk(service, "service name")
        self.settings = settings
        self.instance = settings.instance
        self.keys = Keys(settings.robot)
        self.log = logging.getLogger(f"avs.{service}")
        self.metrics = Metrics(service, self.instance)
        self._owns_session = session is None
        self.session = session if session is not None else open_session(settings)
        self._stop = threading.Event()
        self._signalled = False  # SIGINT / SIGTERM came (``install_signal_handlers``)
        self._threads: list[threading.Thread] = []
        self._subscribers: list[Any] = []
        self._entities: list[Any] = []  # publishers and queryables
        self._token: Any = None
        self.serve(self.keys.metrics(service, self.instance), lambda _req: self.metrics.snapshot())
        if announce:
            self.announce()

    def announce(self) -> None:
        """Declare ``alive/<service>/<instance>``: the node is up and ready."""
        if self._token is None:
            alive = self.keys.alive(self.service, self.instance)
            self._token = self.session.liveliness().declare_token(alive)
            self.log.info("node up", extra={"robot": self.settings.robot, "alive": alive})

    # -- inputs -------------------------------------------------------------------------------

    def decode(self, key: str, payload: bytes, expect: type[M]) -> M | None:
        """``payload`` as an ``expect`` message, or None: dropped and counted by its fault."""
        try:
            message = decode(payload, expect)
        except CodecError as e:
            self.drop(f"{e.kind}", key, str(e))
            return None
        self.metrics.count_valid(key)
        return message

    def drop(self, reason: str, key: str, detail: str) -> None:
        """Count a dropped input by ``reason``; log the first of each reason."""
        if self.metrics.drop(reason):
            self.log.warning(
                "dropping message: %s (further drops for this reason are only counted)",
                detail,
                extra={"key": key, "reason": reason},
            )

    def _handle(
        self,
        name: str,
        handler: Callable[..., Any],
        message: Message | list[Message],
        key: str,
        with_key: bool,
    ) -> None:
        t0 = time.perf_counter()
        try:
            handler(message, key) if with_key else handler(message)
        except Exception as e:
            self.drop(f"handler_error:{type(e).__name__}", key, f"{name} raised {e!r}")
            self.log.debug("handler error", exc_info=True)
        finally:
            self.metrics.record(name, time.perf_counter() - t0)

    def subscribe(
        self,
        key: str,
        message_type: type[M],
        handler: Callable[..., Any],
        *,
        latest_only: bool = False,
        queue: int = 0,
        name: str | None = None,
        with_key: bool = False,
        accept: Callable[[bytes], bool] | None = None,
        nice: int | None = None,
        batch: bool = False,
    ) -> Subscription:
        """Call ``handler`` with every valid ``message_type`` published on ``key`` (and the
        sample's key, with ``with_key``).

        By default the handler runs in Zenoh's callback: keep it light. With ``queue=N`` it
        runs on a thread of its own, in arrival order, with at most N samples waiting (the
        oldest go first when it falls behind). With ``latest_only`` it runs on a thread of its
        own and always gets the newest *valid* sample: up to ``LATEST_RING`` waiting samples
        are looked at newest first, so garbage published on the key cannot evict a good one;
        each is validated and counted (a valid one a newer one replaced as ``superseded``, and
        in ``messages_valid``: it arrived, whole). ``accept`` sees the raw payload first
        (e.g. ``codec.peek``): a sample it refuses is not decoded at all. ``nice`` (with a
        thread of its own): that thread at ordinary scheduling and this nice value, whatever its
        process's (e.g. image work beside a real-time loop, or deferrable work at
        ``realtime.BACKGROUND``). ``batch`` (with ``queue``): the handler gets a list, every
        valid sample waiting when it is called, in arrival order (one call per turn: a handler
        that falls behind works through what waited at once, e.g. publishing one result for
        all of them).
        """
        if batch and (queue <= 0 or latest_only or with_key):
            raise ValueError("batch needs a queue, and neither latest_only nor with_key")
        name = name or getattr(handler, "__name__", key)

        def validated(sample: zenoh.Sample) -> tuple[str, M | None]:
            k = str(sample.key_expr)
            self.metrics.count_in(k)
            payload = sample.payload.to_bytes()
            if accept is not None and not accept(payload):
                return k, None
            return k, self.decode(k, payload, message_type)

        def on_sample(sample: zenoh.Sample) -> None:
            k, message = validated(sample)
            if message is not None:
                self._handle(name, handler, message, k, with_key)

        if not latest_only and queue <= 0:
            self._subscribers.append(self.session.declare_subscriber(key, on_sample))
            return Subscription(self, self._subscribers[-1])
        ring = LATEST_RING if latest_only else queue
        subscriber = self.session.declare_subscriber(key, zenoh.handlers.RingChannel(ring))
        self._subscribers.append(subscriber)

        def newest_valid(first: zenoh.Sample) -> None:
            waiting = [first]
            while (sample := subscriber.handler.try_recv()) is not None:
                waiting.append(sample)
            newest: tuple[str, M] | None = None
            for sample in reversed(waiting):  # every one validated and counted, newest first
                k, message = validated(sample)
                if message is None:
                    continue
                if newest is None:
                    newest = (k, message)
                else:  # a valid sample a newer one replaced
                    self.metrics.drop("superseded")
            if newest is not None:
                self._handle(name, handler, newest[1], newest[0], with_key)

        def every_valid(first: zenoh.Sample) -> None:
            waiting = [first]
            while (sample := subscriber.handler.try_recv()) is not None:
                waiting.append(sample)
            messages = [m for _, m in map(validated, waiting) if m is not None]
            if messages:
                self._handle(name, handler, messages, str(first.key_expr), False)

        take = newest_valid if latest_only else every_valid if batch else on_sample

        def pump() -> None:
            if nice is not None:
                ordinary(nice)
            while not self._stop.is_set():
                try:
                    take(subscriber.handler.recv())
                except zenoh.ZError:  # channel closed: undeclared or session closed
                    return

        self.start_thread(pump, f"{self.service}:{name}")
        return Subscription(self, subscriber)

    def inbox(self, key: str, message_type: type[M], size: int = LATEST_RING) -> Inbox[M]:
        """``key``'s samples kept for a loop of the service's own to take (``Inbox.take``), with
        no callback and no thread: no wake-up per message, and the loop applies them at a point
        of its choosing (the sim's physics loop, head commands between two steps). At most
        ``size`` wait; when the loop falls behind, the oldest are overwritten (``take`` counts a
        full ring as ``inbox_full``)."""
        ring = zenoh.handlers.RingChannel(size)
        subscriber = self.session.declare_subscriber(key, ring)
        self._subscribers.append(subscriber)
        return Inbox(self, subscriber, message_type, size)

    def serve(
        self,
        key: str,
        handler: Callable[[Any], Message | Iterable[Message]],
        request_type: type[Message] | None = None,
        *,
        name: str | None = None,
    ) -> None:
        """Answer queries on ``key``: ``handler(request)`` returns the reply message(s); the
        request is the decoded query payload (None without one). Errors are replied as
        ``QueryError`` and counted."""
        name = name or getattr(handler, "__name__", key)

        def on_query(query: zenoh.Query) -> None:
            k = str(query.key_expr)
            self.metrics.count_in(k)
            request = None
            if query.payload is not None and request_type is not None:
                try:
                    request = decode(query.payload.to_bytes(), request_type)
                except CodecError as e:
                    self.drop(e.kind, k, str(e))
                    query.reply_err(encode(QueryError(error=str(e))))
                    return
            t0 = time.perf_counter()
            try:
                result = handler(request)
                replies = [result] if isinstance(result, Message) else result
                reply_key = k if "*" in key else key
                for message in replies:  # a generator's pages go out as they are made
                    query.reply(reply_key, encode(message))
                    self.metrics.count_out(reply_key)
            except Exception as e:
                self.drop(f"handler_error:{type(e).__name__}", k, f"{name} raised {e!r}")
                query.reply_err(encode(QueryError(error=f"{type(e).__name__}: {e}")))
            finally:
                self.metrics.record(name, time.perf_counter() - t0)

        self._entities.append(self.session.declare_queryable(key, on_query))

    # -- outputs ------------------------------------------------------------------------------

    def publisher(self, key: str, **options: Any) -> Output:
        """A publisher with the key table's QoS for ``key`` (``options`` override it)."""
        output = Output(self, key, **options)
        self._entities.append(output)
        return output

    def query(
        self,
        selector: str,
        request: Message | None = None,
        reply_type: type[M] = Message,  # type: ignore[assignment]
        timeout: float = 5.0,
        every_reply: bool = False,
    ) -> list[M]:
        """Ask every matching queryable; returns the decoded replies. An error reply raises
        ``RemoteError``; an undecodable reply is dropped and counted. ``every_reply``: keep
        several replies on one key (the pages of a paged reply), which Zenoh otherwise
        consolidates to the last."""
        payload = encode(request) if request is not None else None
        replies: list[M] = []
        options = {"consolidation": zenoh.ConsolidationMode.NONE} if every_reply else {}
        for reply in self.session.get(selector, payload=payload, timeout=timeout, **options):
            if reply.ok is None:
                text = reply.err.payload.to_bytes() if reply.err else b""
                try:
                    text = decode(text, QueryError).error
                except CodecError:
                    text = text.decode(errors="replace")
                raise RemoteError(f"{selector}: {text}")
            message = self.decode(selector, reply.ok.payload.to_bytes(), reply_type)
            if message is not None:
                replies.append(message)
        return replies

    # -- life cycle ---------------------------------------------------------------------------

    def start_thread(self, target: Callable[[], None], name: str) -> threading.Thread:
        """Run ``target`` on a daemon thread named ``name`` (``service:what``), joined when the
        node stops taking inputs (``stop_inputs``)."""

        def named() -> None:
            os_thread_name(name.split(":", 1)[-1])  # the process says which service
            target()

        thread = threading.Thread(target=named, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)
        return thread

    def every(self, period: float, callback: Callable[[], Any], name: str | None = None) -> None:
        """Run ``callback`` every ``period`` seconds on a thread until the node stops; errors
        are counted like handler errors."""
        name = name or getattr(callback, "__name__", "periodic")

        def loop() -> None:
            next_t = time.monotonic()
            while not self._stop.is_set():
                t0 = time.perf_counter()
                try:
                    callback()
                except Exception as e:
                    self.drop(f"handler_error:{type(e).__name__}", name, f"{name} raised {e!r}")
                self.metrics.record(name, time.perf_counter() - t0)
                next_t += period
                delay = next_t - time.monotonic()
                if delay < 0:  # overran: skip the missed ticks instead of bursting
                    next_t = time.monotonic()
                    delay = 0
                self._stop.wait(delay)

        self.start_thread(loop, f"{self.service}:{name}")

    @property
    def stopping(self) -> bool:
        """Stopped, or a signal came (``spin`` stops the node on it, but a service may not be
        spinning yet: a standby waiting for its turn in its constructor must not take over)."""
        return self._signalled or self._stop.is_set()

    def stop(self) -> None:
        self._stop.set()

    def wait(self, seconds: float) -> bool:
        """Sleep ``seconds`` or until the node stops (True: it did)."""
        return self._stop.wait(seconds)

    def install_signal_handlers(self) -> None:
        """SIGINT and SIGTERM stop the node (main thread only). The handler only notes the
        signal; ``spin`` stops the node. Setting the stop event in the handler could deadlock
        on the event's own lock (the handler runs on the main thread, which may hold it inside
        ``spin``'s wait), and a wait without a timeout may never run the handler at all when
        the signal lands on another thread (Ctrl-C under ``avs up``: SIGINT, then SIGTERM
        from the supervisor; 7 idle nodes in 20 never stopped)."""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)

    def _on_signal(self, _signum: int, _frame: Any) -> None:
        self._signalled = True

    def spin(self, timeout: float | None = None) -> None:
        """Block until ``stop()`` (or a signal, after ``install_signal_handlers``), or
        ``timeout``; waking every ``SPIN_S`` to act on a signal."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._signalled:
            left = SPIN_S if deadline is None else min(SPIN_S, deadline - time.monotonic())
            if left <= 0 or self._stop.wait(left):
                break
        if self._signalled:
            self.stop()

    def stop_inputs(self) -> None:
        """Stop taking inputs and let the work in flight finish: the node stops, its
        subscribers go (which ends the latest-only and queued pumps) and its threads are
        joined (5 s each at most). ``run_node`` calls it before the service closes what its
        handlers use (the scene memory's journal: an observation fused while it closed was
        lost as ``write to closed file``)."""
        self.stop()
        self._undeclare(self._subscribers)
        for thread in self._threads:
            thread.join(timeout=5.0)

    def close(self) -> None:
        """Stop: inputs first (which also ends latest-only pumps), then the node's threads, then
        outputs, queryables and the liveliness token, then the session."""
        self.stop_inputs()
        self._undeclare(self._entities)
        self._undeclare([self._token] if self._token is not None else [])
        if self._owns_session:
            self.session.close()
        self.log.info("node down")

    def _undeclare(self, entities: list[Any]) -> None:
        for entity in reversed(entities):
            try:
                entity.undeclare()
            except Exception:
                self.log.debug("undeclare failed", exc_info=True)
        entities.clear()

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
