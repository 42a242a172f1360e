"""``avs status``: the live services (their liveliness tokens) and what each one's metrics say:
uptime, messages in and out, drops, gauges. The services expected are those the running
``avs up`` supervises (its ``supervisor`` queryable) and any named with ``--expect``; the exit
status is 1 when one of them is down (named on stderr), or when nothing is live at all."""

from __future__ import annotations

import argparse
import json
import sys

from avs.commands._transport import add_transport_arguments, connect, settings_from


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help="list the live services and their metrics",
                       description=__doc__)  # fmt: skip
    add_transport_arguments(p)
    p.add_argument("--json", action="store_true", help="one JSON object per service")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for answers")
    p.add_argument(
        "--expect",
        default="",
        metavar="NAME,…",
        help="services that must be live (in addition to what avs up supervises)",
    )
    p.set_defaults(func=_status)


def live_services(session, keys, timeout: float) -> list[tuple[str, str]]:
    """(service, instance) of every liveliness token under the robot's alive/."""
    found = set()
    for reply in session.liveliness().get(keys.alive(), timeout=timeout):
        if reply.ok:
            parts = str(reply.ok.key_expr).split("/")
            if len(parts) == 5:
                found.add((parts[3], parts[4]))
    return sorted(found)


def table(rows: list[dict]) -> str:
    """The live services as a table whose columns fit their longest entry: uptime in seconds,
    messages in and out, and the dropped ones as ``reason=n`` (``-``: none; ``?``: the
    service did not answer the metrics query)."""

    def dropped(r: dict) -> str:
        if "dropped" not in r:
            return "?"
        return ", ".join(f"{k}={n}" for k, n in sorted(r["dropped"].items()) if n) or "-"

    header = ("service", "instance", "uptime_s", "in", "out", "dropped")
    cells = [header] + [
        (r["service"], r["instance"], str(r.get("uptime_s", "?")), str(r.get("in", "?")),
         str(r.get("out", "?")), dropped(r))
        for r in rows
    ]  # fmt: skip
    widths = [max(len(c[i]) for c in cells) for i in range(len(header))]
    right = (False, False, True, True, True, False)
    lines = [
        "  ".join(
            (c.rjust(w) if r else c.ljust(w)) for c, w, r in zip(row, widths, right, strict=True)
        ).rstrip()
        for row in cells
    ]
    return "\n".join(lines)


def _status(args: argparse.Namespace) -> int:
    from schemas import CodecError, Keys, ServiceMetrics, SupervisorStatus, decode

    settings = settings_from(args, instance="status")
    keys = Keys(settings.robot)
    rows, down = [], []
    with connect(settings) as session:
        live = live_services(session, keys, args.timeout)
        metrics: dict[tuple[str, str], ServiceMetrics] = {}
        # one query for every instance's metrics: a busy service costs its own wait only
        for reply in session.get(keys.metrics(), timeout=args.timeout):
            if reply.ok:
                try:
                    m = decode(reply.ok.payload.to_bytes(), ServiceMetrics)
                except CodecError:
                    continue
                metrics[(m.service, m.instance)] = m
        supervised = []
        for reply in session.get(keys.supervisor(), timeout=min(args.timeout, 2.0)):
            if reply.ok:
                try:
                    supervised += decode(reply.ok.payload.to_bytes(), SupervisorStatus).services
                except CodecError:
                    continue
    for service, instance in live:
        row = {"service": service, "instance": instance}
        m = metrics.get((service, instance))
        if m is not None:
            row |= {"uptime_s": round(m.uptime_s, 1), "in": sum(m.messages_in.values()),
                    "out": sum(m.messages_out.values()), "dropped": m.dropped,
                    "gauges": m.extra}  # fmt: skip
        rows.append(row)
    live_set = set(live)
    for s in supervised:
        if not s.alive and (f"{s.service}_standby", s.instance) not in live_set:
            down.append({"service": s.service, "instance": s.instance, "state": s.state,
                         "restarts": s.restarts})  # fmt: skip
    live_names = {service.removesuffix("_standby") for service, _ in live}
    for name in (n.strip() for n in args.expect.split(",") if n.strip()):
        if name not in live_names and not any(d["service"] == name for d in down):
            down.append({"service": name, "instance": "*", "state": "not live", "restarts": 0})
    if args.json:
        for row in rows:
            print(json.dumps(row))
        for row in down:
            print(json.dumps(row | {"down": True}))
    elif rows:
        print(table(rows))
    for d in down:
        print(f"avs status: {d['service']} ({d['instance']}) is down: {d['state']}, "
              f"{d['restarts']} restarts", file=sys.stderr)  # fmt: skip
    if not rows and not down:
        print(f"no live services of robot {settings.robot!r}", file=sys.stderr)
        return 1
    return 1 if down else 0
