"""The live service: source -> ring buffer -> sliding-window observer -> Zenoh and MCAP.

Start with :class:`observer.service.daemon.Daemon` (threads, start and stop
order); a sample enters in :class:`observer.service.ringbuffer.RingBuffer`, is
estimated window by window in
:class:`observer.service.window_observer.SlidingWindowObserver`, and leaves
through :mod:`observer.service.zenohpub` and :mod:`observer.service.mcaplog`;
:mod:`observer.service.zenohconf` builds every Zenoh session (keys, TLS,
passwords, access control) and :mod:`observer.service.sdnotify` talks to systemd;
:mod:`observer.service.circuit_worker` estimates the armature in a second process,
:mod:`observer.service.threads` keeps BLAS to one thread.

Import rule: this package may import ``observer.service``,
``observer.estimation``, ``observer.recording``, ``observer.config`` and
``drivers``; never the simulator, the diagnosis or the CLI (checked by
``tests/test_architecture.py``).
"""
