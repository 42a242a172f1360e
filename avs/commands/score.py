"""``avs score``: an outside evaluator of a running system. It asks the scene memory for its
model (``memory/scene``) and its registered cloud (``memory/cloud``: every point the robot
mapped, where the robot believes it is), the sim for its ground truth (``sim/ground_truth``),
and prints how right the model is: the support graph's precision, recall and F1 (Eq.
4.14-4.16, the episode's rules: every perceived edge judged, an edge from a primitive of no
body a false positive) and InlierIndex (Eq. 3.11). The cloud's points are labelled by the
ground truth's body boxes (``evaluation.label_by_boxes``; the episode labels each view's
pixels by the sim's segmentation instead, which an outside evaluator does not have). It only
queries: the ``observer`` identity may run it."""

from __future__ import annotations

import argparse
import json
import sys

from avs.commands._transport import add_transport_arguments, connect, settings_from


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("score", help="score the running system's scene model against the truth",
                       description=__doc__)  # fmt: skip
    add_transport_arguments(p)
    p.add_argument("--scene", default=None, metavar="S",
                   help="the scene the sim must run (a check; default: whichever)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for answers")
    p.set_defaults(func=_score)


def score(session, keys, timeout: float) -> dict:
    """The scores of what the running system holds now (see the module's docstring)."""
    import numpy as np

    from experiments import evaluation
    from schemas import GroundTruth, GroundTruthQuery, PointCloud, SceneModel, decode, encode

    def ask(key: str, schema, payload=None):
        for reply in session.get(key, payload=payload, timeout=timeout):
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), schema)
        raise SystemExit(f"avs score: nothing answered on {key} within {timeout:g} s")

    gt = ask(keys.ground_truth(), GroundTruth,
             encode(GroundTruthQuery(segmentation=False)))  # fmt: skip
    model = ask(keys.scene(), SceneModel)
    cloud = ask(keys.cloud(), PointCloud)
    segments = evaluation.label_by_boxes(gt, cloud.points)
    scores = evaluation.score_primitives(segments, model.primitives,
                                         scope=evaluation.bodies_in_roi(gt))  # fmt: skip
    edges = [(e.supporter, e.supported) for e in model.support_edges]
    support = evaluation.score_support(gt, edges, scores.bodies)
    return {
        "scene": gt.scene,
        "support_precision": round(support.precision, 4),
        "support_recall": round(support.recall, 4),
        "support_f1": round(support.f1, 4),
        "inlier_index": round(scores.inlier_index, 4),
        "primitives": len(model.primitives),
        "support_edges": [list(e) for e in evaluation.edge_names(edges, scores.bodies)],
        "false_edges": [list(e) for e in support.false_positives],
        "true_edges": sorted(map(list, gt.support_edges)),
        "n_views": model.n_views,
        "cloud_points": len(cloud.points),
        "labelled_points": int(sum(len(v) for v in segments.values())),
        "bodies_seen": sorted(segments),
        "unlabelled_share": round(
            1 - sum(len(v) for v in segments.values()) / max(1, len(cloud.points)), 4
        ),
        "roi": [np.asarray(gt.roi_min).tolist(), np.asarray(gt.roi_max).tolist()]
        if gt.roi_min is not None
        else None,
    }


def _score(args: argparse.Namespace) -> int:
    from schemas import Keys

    settings = settings_from(args, instance="score")
    keys = Keys(settings.robot)
    with connect(settings) as session:
        result = score(session, keys, args.timeout)
    if args.scene and not result["scene"].endswith(args.scene.removesuffix(".xml")):
        print(f"avs score: the sim runs {result['scene']!r}, not {args.scene!r}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{result['scene']}: support precision {result['support_precision']:.2f}, "
              f"recall {result['support_recall']:.2f}, F1 {result['support_f1']:.2f}; "
              f"InlierIndex {result['inlier_index']:.3f}; {result['primitives']} primitives, "
              f"{result['n_views']} views")  # fmt: skip
        for a, b in result["false_edges"]:
            print(f"  false: {a} supports {b}")
    return 0
