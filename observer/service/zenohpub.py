"""Zenoh output: estimates and health as JSON, and a queryable answering with the latest estimate.

Keys: ``dcobserver/<drive_id>/estimate``, ``dcobserver/<drive_id>/health``,
``dcobserver/<drive_id>/event`` (confirmed changes, tachometer alarms),
``dcobserver/<drive_id>/latest`` (queryable), with ``/<motor_id>`` after the
drive when one is configured (:func:`observer.service.zenohconf.key`); TLS,
user/password and access control as configured
(:mod:`observer.service.zenohconf`). ``put`` uses congestion control
DROP, so publishing never blocks the observer. The session is opened in a
background thread and retried every ``retry_s`` while it fails (router or
peer unreachable, port in use): meanwhile estimates are counted as not
published and everything else goes on.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from observer.config import ZenohConfig
from observer.service.zenohconf import key, session_json, zenoh_error

log = logging.getLogger(__name__)

#: Queries of ``latest`` waiting for an answer; beyond it the oldest is dropped.
QUERY_BACKLOG = 16


class ZenohPublisher:
    """Publishes estimates and health; opens its session in the background."""

    def __init__(self, config: ZenohConfig, drive_id: str, motor_id: str = "") -> None:
        self.config = config
        self.drive_id = drive_id
        self.motor_id = motor_id
        self._session: Any = None
        self._publishers: dict[str, Any] = {}
        self._queryable: Any = None
        self._latest: bytes | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._health: dict[str, Any] = {
            "state": "disabled" if not config.enabled else "connecting",
            "published": 0,
            "not_published": 0,
            "errors": 0,
            "queries": 0,
            "last_error": "",
        }
        self._thread = threading.Thread(target=self._connect_loop, name="zenoh-open", daemon=True)
        self._server: threading.Thread | None = None

    def _key(self, leaf: str) -> str:
        return key(self.drive_id, leaf, self.motor_id)

    def start(self) -> None:
        if self.config.enabled:
            self._thread.start()

    def _connect_loop(self) -> None:
        import zenoh

        while not self._stop.is_set():
            try:
                text = session_json(self.config, self.config.mode)
                session = zenoh.open(zenoh.Config.from_json5(text))
                drop = zenoh.CongestionControl.DROP
                publishers = {
                    leaf: session.declare_publisher(self._key(leaf), congestion_control=drop)
                    for leaf in ("estimate", "health", "event")
                }
                # A channel, served by a thread of ours, not a Python callback: zenoh runs a
                # callback in a thread of its own, daemonic here, which the interpreter
                # could finalize while it waits inside Zenoh (an abort at exit).
                queryable = session.declare_queryable(
                    self._key("latest"), zenoh.handlers.RingChannel(QUERY_BACKLOG)
                )
            except Exception as exc:
                with self._lock:
                    self._health["errors"] += 1
                    self._health["last_error"] = zenoh_error(exc)
                    self._health["state"] = "unreachable"
                log.warning(
                    "zenoh: cannot open session (%s); estimating goes on, retry in %g s",
                    self._health["last_error"], self.config.retry_s,
                )  # fmt: skip
                self._stop.wait(self.config.retry_s)
                continue
            with self._lock:
                if self._stop.is_set():
                    session.close()
                    return
                self._session = session
                self._publishers = publishers
                self._queryable = queryable
                self._health["state"] = "open"
                self._server = threading.Thread(
                    target=self._serve, args=(queryable.handler,), name="zenoh-latest",
                    daemon=True,
                )  # fmt: skip
                self._server.start()
            log.info(
                "zenoh: publishing on %s (listen %s, connect %s)",
                self._key("{estimate,health,event,latest}"),
                ",".join(self.config.listen) or "-", ",".join(self.config.connect) or "-",
            )  # fmt: skip
            return

    def wait_for_subscriber(self, timeout: float) -> bool:
        """Wait until a subscriber matches the estimate key.

        A connected transport is not enough: until the subscriber's declaration
        has reached this session, puts are not routed to it. Returns False if no
        subscriber matched within ``timeout`` seconds (or Zenoh is off).
        """
        if not self.config.enabled:
            return False
        deadline = time.monotonic() + timeout
        while not self._stop.is_set():
            publisher = self._publishers.get("estimate")
            if publisher is not None:
                try:
                    if publisher.matching_status.matching:
                        return True
                except Exception:  # a publisher closing under us: not matched
                    pass
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self._stop.wait(min(0.02, remaining))
        return False

    def _serve(self, handler: Any) -> None:
        """Answer the queries of ``latest`` until the queryable is undeclared.

        ``handler`` is the queryable's channel (receiving from it, not from the
        queryable, leaves the queryable free to be undeclared meanwhile).
        """
        while True:
            try:
                query = handler.recv()
            except Exception:  # undeclared: its channel is closed
                return
            self._on_query(query)
            del query  # a query is finished (its final reply sent) when it is dropped

    def _on_query(self, query: Any) -> None:
        # Only reads a reference and replies, never blocks.
        latest = self._latest
        self._health["queries"] += 1
        try:
            if latest is not None:
                query.reply(self._key("latest"), latest)
        except Exception as exc:
            self._health["errors"] += 1
            self._health["last_error"] = f"reply: {exc}"

    def publish(self, leaf: str, payload: bytes) -> bool:
        """Put ``payload`` on this observer's ``leaf`` key; False if not connected."""
        if leaf == "estimate":
            self._latest = payload
        publisher = self._publishers.get(leaf)
        if publisher is None:
            with self._lock:
                self._health["not_published"] += 1
            return False
        try:
            publisher.put(payload)
        except Exception as exc:
            with self._lock:
                self._health["errors"] += 1
                self._health["last_error"] = str(exc)
            return False
        with self._lock:
            self._health["published"] += 1
        return True

    def health(self) -> dict[str, Any]:
        """Counters, and whether any subscriber matches the estimates now.

        ``subscriber_matched`` stays false where access control keeps this drive's
        estimates from everyone (its identity not listed for the drive): Zenoh drops
        denied messages without an error, so this is where a wrong grant shows.
        """
        with self._lock:
            health = dict(self._health)
        publisher = self._publishers.get("estimate")
        try:
            health["subscriber_matched"] = bool(
                publisher is not None and publisher.matching_status.matching
            )
        except Exception:  # a publisher closing under us: not matched
            health["subscriber_matched"] = False
        return health

    def threads(self) -> tuple[threading.Thread, ...]:
        """The threads this publisher started: the one opening the session, the one
        answering queries."""
        started = (self._thread, self._server)
        return tuple(t for t in started if t is not None and t.ident is not None)

    def close(self, timeout: float = 10.0) -> None:
        """Undeclare and close the session (reverse order of opening).

        Waits up to ``timeout`` seconds each for the threads opening the session and
        answering queries: a thread left inside a Zenoh call when the interpreter
        exits aborts the process ("FATAL: exception not rethrown", status -6).
        """
        self._stop.set()
        if self._thread.ident is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        with self._lock:
            session, self._session = self._session, None
            publishers, self._publishers = self._publishers, {}
            queryable, self._queryable = self._queryable, None
            if self.config.enabled:
                self._health["state"] = "closed"
        try:
            if queryable is not None:
                queryable.undeclare()
            for publisher in publishers.values():
                publisher.undeclare()
            if session is not None:
                session.close()
        except Exception as exc:
            log.warning("zenoh: error while closing: %s", exc)
        if self._server is not None:
            self._server.join(timeout)
