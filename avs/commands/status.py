"""``avs status``: the live services (their liveliness tokens) and what each one's metrics say:
uptime, messages in and out, drops, gauges."""

from __future__ import annotations

import argparse
import json

from avs.commands._transport import add_transport_arguments, settings_from


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help="list the live services and their metrics",
                       description=__doc__)  # fmt: skip
    add_transport_arguments(p)
    p.add_argument("--json", action="store_true", help="one JSON object per service")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for answers")
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


def _status(args: argparse.Namespace) -> int:
    from schemas import Keys, ServiceMetrics, decode
    from services.common.transport import open_session

    settings = settings_from(args, instance="status")
    keys = Keys(settings.robot)
    rows = []
    with open_session(settings) as session:
        for service, instance in live_services(session, keys, args.timeout):
            row = {"service": service, "instance": instance}
            for reply in session.get(keys.metrics(service, instance), timeout=args.timeout):
                if reply.ok:
                    m = decode(reply.ok.payload.to_bytes(), ServiceMetrics)
                    row |= {"uptime_s": round(m.uptime_s, 1), "in": sum(m.messages_in.values()),
                            "out": sum(m.messages_out.values()), "dropped": m.dropped,
                            "gauges": m.extra}  # fmt: skip
            rows.append(row)
    if args.json:
        for row in rows:
            print(json.dumps(row))
        return 0
    if not rows:
        print(f"no live services of robot {settings.robot!r}")
        return 1
    print(f"{'service':<14}{'instance':<22}{'uptime':>9}{'in':>10}{'out':>10}  dropped")
    for r in rows:
        print(f"{r['service']:<14}{r['instance']:<22}{r.get('uptime_s', '?'):>9}"
              f"{r.get('in', '?'):>10}{r.get('out', '?'):>10}  {r.get('dropped', {})}")  # fmt: skip
    return 0
