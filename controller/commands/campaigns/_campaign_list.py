"""``heliocal campaign list --db DB [--long] [--json]``: the nights recorded in a database, each
with its campaigns (a calibration night's campaign, a planned night's passes), then campaigns
that belong to no night (recorded before nights were).

Each line fits :data:`WIDTH` columns (a terminal's, a log's): a night names how many lamps it
lit and a line that would be longer is cut with ``…``; a night that ended before any campaign
(at its first lamp change) has its cause on the next line; ``--long`` prints every detail in
full (the lamps, each night's and campaign's cause), ``--json`` all of it as data.

A pass measures (``measured``), a calibration campaign calibrates (``calibrated``): each row
counts what its campaign was for, so a pass whose heliostats were all measured reads
``measured 2/2``, never ``0/2 calibrated``.
"""

from __future__ import annotations

import argparse

from controller.commands.common import print_json

WIDTH = 120


def _row(store, c) -> dict:
    runs = store.runs(c.id)
    return {"id": c.id, "name": c.name, "night": c.started_utc[:10], "status": c.status, "cause": c.cause,
            "heliostats": len(c.queue), "recorded": len(runs),
            "calibrated": sum(r.status == "calibrated" for r in runs),
            "measured": sum(r.status == "measured" for r in runs), "target": c.target, "lamp": c.light_source}


def list_campaigns(args: argparse.Namespace) -> int:
    from controller.storage.db import open_existing
    from controller.storage.nights import NightBook, night_of

    with open_existing(args.db) as store:
        passes = NightBook(store).passes()
        rows = [{**_row(store, c), "pass": c.id in passes} for c in store.campaigns()]
        nights = []
        recorded = NightBook(store).nights()
        owner = {r["id"]: night_of(r["name"], [n.name for n in recorded]) for r in rows}
        for n in recorded:
            mine = [r for r in rows if owner[r["id"]] == n.name]
            s = n.summary
            nights.append({"index": n.index, "name": n.name, "kind": n.kind, "status": n.status,
                           "cause": n.cause,
                           "started_utc": n.started_utc, "finished_utc": n.finished_utc,
                           "planned": s.get("planned"), "measured": s.get("measured"),
                           "lamps": [x["lamp"] for x in s.get("lamps", [])],
                           "daytime_error_predicted_mrad": s.get("daytime_error_predicted_mrad"),
                           "daytime_error_true_mrad": s.get("truth", {}).get("daytime_error_mrad"),
                           "campaigns": [r["id"] for r in mine]})
    if args.json:
        print_json({"nights": nights, "campaigns": rows})
        return 0
    if not rows and not nights:
        print(f"{args.db}: no campaign recorded")
        return 0
    out = print if args.long else (lambda line: print(_fit(line)))
    shown: set[int] = set()
    for n in nights:
        out(_night_line(n, args.long))
        if n["cause"] and not n["campaigns"] and not args.long:  # no pass line gives it: why it ended
            out(f"    {n['cause']}")
        for r in rows:
            if r["id"] in n["campaigns"]:
                shown.add(r["id"])
                out(_campaign_line(r, indent="    ", name=r["name"].removeprefix(n["name"] + "/")))
    rest = [r for r in rows if r["id"] not in shown]
    if rest:
        if nights:
            print("campaigns outside any night:")
        print(f"{'id':>4}  {'name':40} {'night':10}  {'status':11} {'done':>10}  cause")
        for r in rest:
            out(_campaign_line(r))
    return 0


def _fit(line: str) -> str:
    """``line`` cut to :data:`WIDTH` columns, ``…`` marking the cut (``--long`` prints it whole)."""
    return line if len(line) <= WIDTH else line[:WIDTH - 1] + "…"


def _night_line(n: dict, long: bool = True) -> str:
    """The night's line: with ``long`` every lamp by name and the night's cause (it names every
    heliostat not measured), else the lamps counted and no cause (the passes' lines give it)."""
    head = f"night {n['index']}: {n['name']} ({n['kind']}), {n['status']}"
    if n["kind"] == "planned" and n["planned"] is not None:
        head += f"; {n['measured']}/{n['planned']} " + ("geometries measured" if long else "measured")
    if n["lamps"]:
        head += f"; lamps {', '.join(n['lamps'])}" if long else \
            f"; {len(n['lamps'])} lamp{'s' if len(n['lamps']) > 1 else ''}"
    p, t = n["daytime_error_predicted_mrad"], n["daytime_error_true_mrad"]
    if p and p.get("rms") is not None:
        head += f"; daytime RMS predicted {p['rms']:.2f} mrad"
        if t and t.get("rms") is not None:
            head += f", true {t['rms']:.2f}" + (" (simulated plant)" if long else "")
    return head + (f" ({n['cause']})" if n["cause"] and long else "")


def _campaign_line(r: dict, indent: str = "", name: str | None = None) -> str:
    measuring = r["pass"]  # a pass measures: "measured 0/2", never "0/2 calibrated"
    done = f"{r['measured'] if measuring else r['calibrated']}/{r['heliostats']}"
    what = "measured" if measuring else "calibrated"
    name = r["name"] if name is None else name
    return (f"{indent}{r['id']:>4}  {name[:40]:40} {r['night']:10}  {r['status']:11} {done:>6} {what}"
            + (f"  {r['cause']}" if r["cause"] else ""))
