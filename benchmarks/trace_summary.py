"""Where a traced step's time goes: the spans of one compiled program's operations in a perfetto trace
(`step_mfu.py --profile DIR` writes DIR/plugins/profile/*/perfetto_trace.json.gz), summed by kind and by
operation.

    python benchmarks/trace_summary.py TRACE.json.gz [--module train_step] [--top 15] [--json]

Only spans that name an HLO operation of a module whose name holds --module are counted, and on an
accelerator only the device's own (a process named /device:GPU or /device:TPU), not the host's launches.
Loops, conditionals and calls are left out (their spans hold their bodies'). Kinds come from the
operation's name: matmul (gemm, dot, cuBLAS, convolution, YNNPACK), random bits (threefry, rng), then
the name's first word (a fusion's XLA kind: loop, input, broadcast, ...). The spans of the device's streams may
overlap: their sum can exceed the step's wall time.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import pathlib
import re

MATMUL = re.compile(r"gemm|dot|cublas|matmul|conv|ynn", re.IGNORECASE)  # ynn: XLA:CPU's YNNPACK fusions
RANDOM = re.compile(r"threefry|rng", re.IGNORECASE)
CONTAINER = re.compile(r"(while|cond|conditional|call)([._]|$)")  # spans that hold their body's spans


def kind(op: str) -> str:
    if MATMUL.search(op):
        return "matmul"
    if RANDOM.search(op):
        return "random bits"
    return re.split(r"[._\-]", op, maxsplit=1)[0] or op


def op_spans(trace: dict, module: str) -> list[tuple[str, float]]:
    """(operation, microseconds) of every counted span."""
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    processes = {e["pid"]: e["args"]["name"] for e in events
                 if e.get("ph") == "M" and e.get("name") == "process_name"}
    devices = {pid for pid, name in processes.items() if re.match(r"/device:(GPU|TPU)", name)}
    spans = []
    for event in events:
        args = event.get("args") or {}
        if event.get("ph") != "X" or "hlo_op" not in args or module not in str(args.get("hlo_module", "")):
            continue
        if (devices and event["pid"] not in devices) or CONTAINER.match(args["hlo_op"]):
            continue
        spans.append((args["hlo_op"], float(event.get("dur", 0.0))))
    return spans


def summary(path: pathlib.Path, module: str, top: int) -> dict:
    try:
        with gzip.open(path) as handle:
            trace = json.load(handle)
    except (OSError, json.JSONDecodeError) as error:
        raise SystemExit(f"trace_summary.py: {path}: not a gzipped JSON trace ({error})") from None
    spans = op_spans(trace, module)
    if not spans:
        raise SystemExit(f"trace_summary.py: {path}: no span names an operation of a module matching {module!r}")
    by_op, by_kind = collections.Counter(), collections.Counter()
    for op, micros in spans:
        by_op[op] += micros
        by_kind[kind(op)] += micros
    total = sum(by_kind.values())
    return {"trace": str(path), "spans": len(spans), "total_ms": round(total / 1e3, 3),
            "by_kind_ms": {k: round(v / 1e3, 3) for k, v in by_kind.most_common()},
            "top_ops_ms": {k: round(v / 1e3, 3) for k, v in by_op.most_common(top)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace", type=pathlib.Path)
    parser.add_argument("--module", default="train_step", help="count the operations of modules whose name holds this")
    parser.add_argument("--top", type=int, default=15, help="how many operations to list")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    report = summary(args.trace, args.module, args.top)
    if args.json:
        print(json.dumps(report))
        return
    total = report["total_ms"]
    print(f"{report['trace']}: {report['spans']} spans, {total:.1f} ms")
    for name, ms in report["by_kind_ms"].items():
        print(f"  {name:40} {ms:10.2f} ms {100 * ms / total:6.1f}%")
    print("  top operations:")
    for name, ms in report["top_ops_ms"].items():
        print(f"  {name[:60]:60} {ms:10.2f} ms")


if __name__ == "__main__":
    main()
