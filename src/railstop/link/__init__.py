"""Train-platform communication link (SPEC §5): telegram codec and EN 50159 safety layer.

``railstop.link.codec`` turns telegrams into bytes and back (type, payload,
CRC-16); ``railstop.link.safety`` wraps those bytes in safety frames
(sequence number, timestamp, ids, CRC-32 or HMAC). The simulated media and
the UDP transport live in ``railstop.link.channel`` and ``railstop.link.udp``; the media's
parameters and presets are data (``railstop.config.media``).

The package itself imports nothing: a command that needs only the codec (``railstop telegram``,
the CLI's help) does not load the media's models with pydantic and numpy. Import the module
used (``from railstop.link.codec import encode``).
"""
