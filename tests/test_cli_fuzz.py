"""Every file argument of every ``heliocal`` command gets every file of the bad-input corpus
(tests/io/badfiles.py): the command must exit 2 with one line naming the file, no traceback,
within a bounded time, and create nothing.

``TABLE`` maps each command (discovered from the argparse tree, like test_cli_help.py) to the
smallest invocation that reaches its reads, with ``{slot}`` placeholders for the files read.
Every option taking a string must be a slot or declared as not read (outputs, names, devices),
so a new command or a new file option without an entry here fails this test. The corpus runs
in-process (fast; SIGALRM bounds each run); a sample runs as real subprocesses as well.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shlex
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "io"))

from badfiles import NOT_REGULAR, write_corpus  # noqa: E402

from controller.cli import build_parser, main  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "docs" / "examples"
AA39 = REPO / "tests" / "data" / "real" / "aa39"
IMAGE, YAML, JSON, CSV, DB, TEXT = "image", "yaml", "json", "csv", "db", "text"
# Files of the corpus that are valid for a kind of slot (a PNG is an image whatever its name).
VALID_FOR = {IMAGE: {"png_named.yaml", "png_named.json", "png_named.csv"}}
NEW_DB = {"empty.png": "sqlite takes an empty file as a new, empty database"}


@dataclass(frozen=True)
class Slot:
    option: str  # the option string, or the positional's metavar
    kind: str
    valid: str  # key of the valid file used while another slot is fuzzed
    skip: dict[str, str] = field(default_factory=dict)  # corpus name -> why it is not bad here
    exit_code: int = 2  # 1 where the file reaches the command as a device's failure


@dataclass(frozen=True)
class Entry:
    argv: str  # {name} = a slot of ``slots``; {out} = the output folder; {v[key]} = a valid file
    slots: dict[str, Slot]
    not_read: dict[str, str] = field(default_factory=dict)  # string option -> what it is instead


OUTPUTS = "an output, checked to stay absent"
TABLE: dict[str, list[Entry]] = {
    "aim": [Entry("aim --config {config} --db {db} --heliostat H01 --sun-az 180 --sun-el 45",
                  {"config": Slot("--config", YAML, "config"), "db": Slot("--db", DB, "db")},
                  {"--heliostat": "a heliostat id", "--time": "a time"})],
    "beam": [Entry("beam {image} --background {background} --mask {mask} --plot {out}/plots",
                   {"image": Slot("IMAGE", IMAGE, "rx"), "background": Slot("--background", IMAGE, "amb"),
                    "mask": Slot("--mask", IMAGE, "rx")}, {"--plot": OUTPUTS})],
    "campaign run": [Entry("campaign run --config {config} --db {db} --camera-manifest {cam}",
                           {"config": Slot("--config", YAML, "config"),
                            "db": Slot("--db", DB, "db", NEW_DB),
                            "cam": Slot("--camera-manifest", YAML, "cam")},
                           {"--name": "a campaign name", "--heliostats": "heliostat ids", "--report": OUTPUTS,
                            "--notify": "a command run at the end"})],
    "campaign list": [Entry("campaign list --db {db}", {"db": Slot("--db", DB, "db")})],
    "campaign flags": [Entry("campaign flags --db {db}", {"db": Slot("--db", DB, "db")},
                             {"--clear": "heliostat ids", "--lamp": "a lamp id"})],
    # The packaged plant has no lamps: section, which a planned night needs and checks right
    # after the configuration: the database and recorded pairs are read as by campaign run.
    "campaign night": [Entry("campaign night --config {config} --db {out}/n.db",
                             {"config": Slot("--config", YAML, "config")},
                             {"--db": "read after the lamps: check, as campaign run's --db",
                              "--camera-manifest": "read after the lamps: check, as campaign run's",
                              "--heliostats": "heliostat ids"})],
    "capture": [
        Entry("capture --camera file --manifest {cam} --config {config} --out {out}/cap",
              {"cam": Slot("--manifest", YAML, "cam"), "config": Slot("--config", YAML, "config")},
              {"--out": OUTPUTS}),
        Entry("capture --camera file --manifest {v[cam_of]}{img} --config {v[config]} --out {out}/cap",
              {"img": Slot("--manifest", IMAGE, "rx", exit_code=1)}),  # a frame the manifest lists: the
        # file camera reports it as a camera failure (exit 1), still in one line naming the file
    ],
    "commission": [Entry("commission --config {config} --heliostat H01 --simulate --status "
                         "--library {lib} --run-dir {out}/run",
                         {"config": Slot("--config", YAML, "config"), "lib": Slot("--library", YAML, "lib")},
                         {"--heliostat": "a heliostat id", "--capture": OUTPUTS, "--run-dir": OUTPUTS,
                          "--store-reference": "a label",
                          "--camera-manifest": "read by FileCamera only after a real drive answered "
                                               "(the same reader is fuzzed through campaign run and "
                                               "console, and in tests/io)"})],
    "console": [Entry("console --config {config} --db {db} --camera-manifest {cam} --library {lib} "
                      "--token-file {token} --host 127.0.0.1 --port 0",
                      {"config": Slot("--config", YAML, "config"), "db": Slot("--db", DB, "db", NEW_DB),
                       "cam": Slot("--camera-manifest", YAML, "cam"), "lib": Slot("--library", YAML, "lib"),
                       "token": Slot("--token-file", TEXT, "token")},
                      {"--heliostats": "heliostat ids", "--reports": "a folder of reports",
                       "--host": "an address", "--token": "a token", "--run-dir": OUTPUTS})],
    "crf fit": [Entry("crf fit {data} --out {out}/crf.yaml --plot {out}/crf.png",
                      {"data": Slot("DATA.csv", CSV, "sphere")}, {"--out": OUTPUTS, "--plot": OUTPUTS})],
    "demo": [Entry("demo --config {config} --heliostats 1 --aim-only --out {out}/demo",
                   {"config": Slot("--config", YAML, "config")}, {"--out": OUTPUTS})],
    "export": [Entry("export --db {db} --format paint --out {out}/e --config {config}",
                     {"db": Slot("--db", DB, "db"), "config": Slot("--config", YAML, "config")},
                     {"--out": OUTPUTS, "--campaign": "a campaign name", "--day": "a date",
                      "--heliostats": "heliostat ids"}),
               Entry("export tracking-table --config {config} --db {db} --day 2026-06-21 --out {out}/t.csv",
                     {"db": Slot("--db", DB, "db"), "config": Slot("--config", YAML, "config")})],
    # The plant-integration commands open the database as a writer: an empty file is a new one.
    "alarms": [Entry("alarms list --db {db}", {"db": Slot("--db", DB, "db", NEW_DB)},
                     {"ID": "an alarm's number", "--for": "a duration", "--comment": "a comment"})],
    "audit": [Entry("audit --db {db}", {"db": Slot("--db", DB, "db", NEW_DB)}, {"--since": "a time"})],
    "users": [Entry("users list --db {db}", {"db": Slot("--db", DB, "db", NEW_DB)},
                    {"NAME": "an account name"}),
              Entry("users add fuzz --role viewer --password-file {pw} --db {v[db]}",
                    {"pw": Slot("--password-file", TEXT, "token")})],
    "opcua": [Entry("opcua --config {config} --db {db} --endpoint opc.tcp://127.0.0.1:1/heliocal",
                    {"config": Slot("--config", YAML, "config"), "db": Slot("--db", DB, "db", NEW_DB)},
                    {"--endpoint": "an address", "--heliostats": "heliostat ids", "--pki": OUTPUTS})],
    "flux": [
        Entry("flux {rx} --sun {sun} --ambient {amb} --dni 900 --reflectivity 0.9 --crf {crf} "
              "--out {out}/f.npy --png {out}/f.png",
              {"rx": Slot("RECEIVER", IMAGE, "rx"), "sun": Slot("--sun", IMAGE, "sun"),
               "amb": Slot("--ambient", IMAGE, "amb"), "crf": Slot("--crf", YAML, "crf")},
              {"--out": OUTPUTS, "--png": OUTPUTS}),
        Entry("flux --receiver-pair {rlow} {rhigh} --ambient-pair {alow} {ahigh} --exposures 0.01 0.02 "
              "--sun-exposure 0.01 --sun {v[sun]} --dni 900 --reflectivity 0.9 --out {out}/f.npy",
              {"rlow": Slot("--receiver-pair", IMAGE, "rx"), "rhigh": Slot("--receiver-pair", IMAGE, "rx"),
               "alow": Slot("--ambient-pair", IMAGE, "amb"), "ahigh": Slot("--ambient-pair", IMAGE, "amb")}),
    ],
    "glare": [Entry("glare --sun {sun} --source {src} --dni 900 --sun-transmittance 0.01 --png {out}/g.png",
                    {"sun": Slot("--sun", IMAGE, "sun"), "src": Slot("--source", IMAGE, "rx")},
                    {"--png": OUTPUTS})],
    "library build": [
        Entry("library build {manifest} --out {out}/lib.yaml",
              {"manifest": Slot("MANIFEST", CSV, "manifest")}, {"--out": OUTPUTS}),
        Entry("library build {v[manifest_of]}{img} --out {out}/lib.yaml",  # an image the manifest lists
              {"img": Slot("MANIFEST", IMAGE, "rx")}),
    ],
    "match": [Entry("match {image} --library {lib}",
                    {"image": Slot("IMAGE", IMAGE, "rx"), "lib": Slot("--library", YAML, "lib")})],
    "merge": [Entry("merge {low} {high} --exposures 0.01 0.02 --crf {crf} --out {out}/hdr.npy",
                    {"low": Slot("LOW", IMAGE, "amb"), "high": Slot("HIGH", IMAGE, "rx"),
                     "crf": Slot("--crf", YAML, "crf")}, {"--out": OUTPUTS})],
    "model fit": [Entry("model fit {rec} --heliostat-properties {props} --towers {towers} --out {out}/m.json "
                        "--prior {prior} --timestamps {ts}",
                        {"rec": Slot("RECORD.json", JSON, "rec"),
                         "props": Slot("--heliostat-properties", JSON, "props"),
                         "towers": Slot("--towers", JSON, "towers"), "prior": Slot("--prior", JSON, "prior"),
                         "ts": Slot("--timestamps", JSON, "paint_ts")}, {"--out": OUTPUTS})],
    "model prior": [Entry("model prior {model} {v[model_bk20]} --out {out}/p.json",
                          {"model": Slot("MODEL.json", JSON, "model")}, {"--out": OUTPUTS})],
    "model refit": [Entry("model refit --config {config} --db {db}",
                          {"config": Slot("--config", YAML, "config"), "db": Slot("--db", DB, "db")},
                          {"--heliostats": "heliostat ids"})],
    "model predict": [Entry("model predict {model} --record {rec} --towers {towers} --timestamps {ts}",
                            {"model": Slot("MODEL.json", JSON, "model"), "rec": Slot("--record", JSON, "rec"),
                             "towers": Slot("--towers", JSON, "towers"),
                             "ts": Slot("--timestamps", JSON, "paint_ts")})],
    "model validate": [Entry("model validate {rec} --heliostat-properties {props} --towers {towers}",
                             {"rec": Slot("RECORD.json", JSON, "rec"),
                              "props": Slot("--heliostat-properties", JSON, "props"),
                              "towers": Slot("--towers", JSON, "towers")},
                             {"--paint-dir": "a folder: each file in it is read and named "
                                             "(tests/geometry/test_model_real.py)",
                              "--heliostats": "heliostat ids", "--plot": OUTPUTS}),
                       Entry("model validate {v[rec]} --heliostat-properties {v[props]} --towers {v[towers]} "
                             "--split time --train 1 --val 1 --timestamps {ts} --prior {prior} "
                             "--plot {out}/plots",
                             {"ts": Slot("--timestamps", JSON, "paint_ts"),
                              "prior": Slot("--prior", JSON, "prior")},
                             {"--plot": OUTPUTS})],
    "reprocess": [Entry("reprocess --db {db} --out {out}/new.db --workers 1",
                        {"db": Slot("--db", DB, "db")},
                        {"--out": OUTPUTS, "--images": "a folder (frames are read per pair, by workers)",
                         "--since": "a date", "--scheduler": "an address"})],
    "report campaign": [Entry("report campaign --db {db} --out {out}/r", {"db": Slot("--db", DB, "db")},
                              {"--out": OUTPUTS, "--campaign": "a campaign name",
                               "--night": "a night index or name"})],
    "report first-light": [Entry("report first-light --db {db} --out {out}/r", {"db": Slot("--db", DB, "db")},
                                 {"--out": OUTPUTS, "--campaign": "a campaign name"})],
    "report confusion": [
        Entry("report confusion --library {lib} --test {test} --out {out}/r",
              {"lib": Slot("--library", YAML, "lib"), "test": Slot("--test", CSV, "manifest")},
              {"--out": OUTPUTS}),
        Entry("report confusion --library {v[lib]} --test {v[manifest_of]}{img} --out {out}/r",
              {"img": Slot("--test", IMAGE, "rx")}),
    ],
    "report weighting": [Entry("report weighting --config {config} --pairs 2 --out {out}/w",
                               {"config": Slot("--config", YAML, "config")},
                               {"--out": OUTPUTS, "--heliostat": "a heliostat id",
                                "--source": "a light source"})],
    "sim errorset": [Entry("sim errorset --config {config} --cases 1 --views 1 --out {out}/es",
                           {"config": Slot("--config", YAML, "config")},
                           {"--out": OUTPUTS, "--heliostat": "heliostat ids", "--sources": "light source ids",
                            "--magnitudes": "numbers", "--test-heliostats": "heliostat ids",
                            "--test-sources": "light source ids", "--test-magnitudes": "numbers"})],
    "sim plant": [Entry("sim plant --config {config} --write-config {out}/field.yaml",
                        {"config": Slot("--config", YAML, "config")}, {"--write-config": OUTPUTS})],
    "sim lamp-panel": [Entry("sim lamp-panel --config {config}",
                             {"config": Slot("--config", YAML, "config")})],
    "sim field": [Entry("sim field --out {out}/f --heliostats 2 --targets 1", {}, {"--out": OUTPUTS})],
    "sim firmware": [Entry("sim firmware --config {config} --serial-link {out}/pty",
                           {"config": Slot("--config", YAML, "config")},
                           {"--serial-link": OUTPUTS, "--modbus-tcp": "an address",
                            "--modbus-rtu": OUTPUTS, "--units": "unit numbers"})],
    "import paint": [Entry("import paint {v[paint]} --db {db} --config {config} --timestamps {ts}",
                           {"db": Slot("--db", DB, "db", NEW_DB),
                            "config": Slot("--config", YAML, "paint_config"),
                            "ts": Slot("--timestamps", JSON, "paint_ts")},
                           {"DIR": "a folder: each file in it is read and named "
                                   "(tests/storage/test_paint_import.py)"})],
    "lamps": [Entry("lamps --config {config} status", {"config": Slot("--config", YAML, "config")},
                    {"LAMP": "a lamp channel name"})],
    "sun": [Entry("sun --config {config} --time 2026-06-21T12:00:00Z",
                  {"config": Slot("--config", YAML, "config")},
                  {"--time": "a time", "--lat": "a number", "--lon": "a number", "--elevation": "a number",
                   "--pressure": "a number", "--temperature": "a number", "--delta-t": "a number"})],
}
# The drive group: its options (--config among them) precede the sub-command.
_DRIVE = {"--serial": "a device", "--modbus-tcp": "an address", "--modbus-rtu": "a device"}
for _sub in ("status", "info", "limits", "stop", "home", "stow", "clear-fault", "move", "jog"):
    _steps = " --az-steps 0 --el-steps 0" if _sub in ("move", "jog") else ""
    TABLE[f"drive {_sub}"] = [Entry(f"drive --serial {{out}}/nodev --unit 1 --config {{config}} "
                                    f"{_sub}{_steps}", {"config": Slot("--config", YAML, "config")}, _DRIVE)]


def _commands(parser: argparse.ArgumentParser, path: str = "", inherited=()):
    """(command path, its string-valued options and positionals, group options included)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    own = tuple(a for a in parser._actions if not isinstance(a, argparse._SubParsersAction))
    if not subs:
        yield path, inherited + own
    for a in subs:
        for name, sub in a.choices.items():
            yield from _commands(sub, f"{path} {name}".strip(), inherited + (own if path else ()))


def _string_args(actions) -> set[str]:
    names = set()
    for a in actions:
        if a.nargs == 0 or a.type is not None or a.choices is not None or a.dest == "help":
            continue
        names.add(a.option_strings[0] if a.option_strings else str(a.metavar or a.dest))
    return names


def test_table_covers_every_command_and_every_string_argument():
    seen = {}
    for path, actions in _commands(build_parser()):
        assert path in TABLE, f"heliocal {path}: no entry in TABLE (which of its arguments are files read?)"
        declared = set()
        for e in TABLE[path]:
            declared |= {s.option for s in e.slots.values()} | set(e.not_read)
        missing = _string_args(actions) - declared
        assert not missing, f"heliocal {path}: {sorted(missing)} neither fuzzed nor declared not read"
        seen[path] = True
    assert set(TABLE) == set(seen), f"TABLE names commands that do not exist: {set(TABLE) - set(seen)}"


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> dict[str, str]:
    """Valid files for the slots not under test; each is read successfully by its command."""
    import yaml

    from controller.commands.common import PACKAGED_CONFIG
    from controller.imaging.crf import Crf
    from controller.imaging.crf_io import save_crf
    from controller.storage.db import CampaignStore

    d = tmp_path_factory.mktemp("valid")
    v = {"rx": EXAMPLES / "rx.png", "amb": EXAMPLES / "amb.png", "sun": EXAMPLES / "sun.png",
         "config": d / "one.yaml", "sphere": EXAMPLES / "sphere.csv",
         "rec": AA39 / "AA39-calibration-properties_1.json", "props": AA39 / "AA39-heliostat-properties.json",
         "towers": AA39 / "tower-measurements.json", "db": d / "c.db", "crf": d / "crf.yaml",
         "token": d / "token", "manifest": d / "m.csv", "lib": d / "lib.yaml", "cam": d / "cam.yaml",
         "model": d / "model.json"}
    plant = yaml.safe_load(Path(PACKAGED_CONFIG).read_text())
    plant["heliostats"] = plant["heliostats"][:1]  # H01 only: loads 4x faster than the demo plant
    v["config"].write_text(yaml.safe_dump(plant, sort_keys=False))
    CampaignStore(v["db"]).close()
    save_crf(Crf.linear(8), v["crf"])
    v["token"].write_text("a-long-enough-console-token-0123456789\n")
    v["manifest"].write_text(f"image,label\n{EXAMPLES / 'rx.png'},a\n{EXAMPLES / 'sun.png'},b\n")
    v["cam"].write_text(f"pairs:\n  - {{low: {EXAMPLES / 'amb.png'}, high: {EXAMPLES / 'rx.png'}, "
                        "exposures: [0.01, 0.02]}\n")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert main(["library", "build", str(v["manifest"]), "--out", str(v["lib"])]) == 0, err.getvalue()
        assert main(["model", "fit", *map(str, sorted(AA39.glob("AA39-calibration-properties_*.json"))),
                     "--heliostat-properties", str(v["props"]), "--towers", str(v["towers"]),
                     "--out", str(v["model"])]) == 0, err.getvalue()
    # A PAINT folder of one heliostat, its times and the field configuration its import writes.
    paint = REPO / "tests" / "data" / "real" / "paint-field"
    shutil.copytree(paint / "BK20", d / "paint" / "BK20")
    for name in ("tower-measurements.json", "timestamps.json"):
        shutil.copy(paint / name, d / "paint" / name)
    v["paint"], v["paint_ts"] = d / "paint", d / "paint" / "timestamps.json"
    v["paint_config"] = d / "p.config.yaml"  # written beside p.db
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert main(["import", "paint", str(v["paint"]), "--db", str(d / "p.db")]) == 0, err.getvalue()
        v["model_bk20"], v["prior"] = d / "bk20.json", d / "prior.json"
        assert main(["model", "fit", *map(str, sorted((paint / "BK20" / "calibration").glob("*.json"))),
                     "--heliostat-properties", str(paint / "BK20" / "BK20_properties.json"),
                     "--towers", str(v["towers"]), "--out", str(v["model_bk20"])]) == 0, err.getvalue()
        assert main(["model", "prior", str(v["model"]), str(v["model_bk20"]), "--out", str(v["prior"])]) == 0
    # "{v[manifest_of]}{img}": a manifest listing the image under test (written per run)
    return {k: str(p) for k, p in v.items()}


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> list[Path]:
    return write_corpus(tmp_path_factory.mktemp("bad"))


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def _argv(entry: Entry, slot: str, bad: Path, valid: dict[str, str], out: Path) -> list[str]:
    values = {name: valid[s.valid] for name, s in entry.slots.items()}
    values[slot] = str(bad)
    entry_argv = entry.argv
    if "{v[manifest_of]}" in entry.argv:  # the slot is an image listed in a library manifest
        manifest = out.parent / f"lists-{bad.name}.csv"
        manifest.write_text(f"image,label\n{valid['rx']},a\n{bad},b\n")
        values[slot] = ""
        entry_argv = entry.argv.replace("{v[manifest_of]}", str(manifest))
    elif "{v[cam_of]}" in entry.argv:  # the slot is a frame listed in a camera manifest
        manifest = out.parent / f"pairs-{bad.name}.yaml"
        manifest.write_text(f"pairs:\n  - {{low: '{bad}', high: '{valid['rx']}', exposures: [0.01, 0.02]}}\n")
        values[slot] = ""
        entry_argv = entry.argv.replace("{v[cam_of]}", str(manifest))
    return shlex.split(entry_argv.format(out=out, v=valid, **{k: shlex.quote(x) for k, x in values.items()}))


def _cases():
    for path, entries in TABLE.items():
        for i, e in enumerate(entries):
            for name in e.slots:
                yield pytest.param(path, i, name, id=f"{path.replace(' ', '-')}#{i}:{name}")


def _check(argv: list[str], code: int, out: str, err: str, bad: Path, outdir: Path, expect: int = 2) -> None:
    where = f"heliocal {shlex.join(argv)}"
    assert "Traceback" not in out + err, f"{where}\n{err}"
    lines = [ln for ln in err.splitlines() if not ln.startswith("heliocal: using configuration")]
    assert code == expect, f"{where}: exit {code}\n{err}"
    assert len(lines) == 1 and bad.name in lines[0], f"{where}: expected one line naming {bad.name}:\n{err}"
    assert not any(outdir.iterdir()), f"{where}: created {sorted(p.name for p in outdir.iterdir())}"
    beside = sorted(p.name for p in bad.parent.iterdir() if p.name.startswith(bad.name) and p != bad)
    assert not beside, f"{where}: left {beside} beside the file it refused (a lock, a journal)"


@pytest.mark.parametrize("path,index,slot", list(_cases()))
def test_every_bad_file_in_every_slot_is_refused_in_one_line(path, index, slot, valid, bad, tmp_path, scaled):
    entry = TABLE[path][index]
    s = entry.slots[slot]
    outdir = tmp_path / "out"
    outdir.mkdir()
    limit = scaled(5.0)
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for f in bad:
            if f.name in VALID_FOR.get(s.kind, ()) or f.name in s.skip:
                continue
            argv = _argv(entry, slot, f, valid, outdir)
            stdout, stderr = io.StringIO(), io.StringIO()
            t0 = time.perf_counter()
            signal.setitimer(signal.ITIMER_REAL, limit)
            try:
                with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                    code = main(argv)
            except SystemExit as exc:  # argparse
                code = exc.code
            except _Timeout:
                pytest.fail(f"heliocal {shlex.join(argv)}: still running after {limit} s")
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            assert time.perf_counter() - t0 < limit
            # A FIFO, a device or a folder is refused where it is named (exit 2), before any device
            # would read it.
            expect = 2 if f.name in NOT_REGULAR else s.exit_code
            _check(argv, code, stdout.getvalue(), stderr.getvalue(), f, outdir, expect)
    finally:
        signal.signal(signal.SIGALRM, previous)


# A sample as real processes: one corpus file per command family, spread over the kinds.
SAMPLE = [("beam", 0, "image", "bomb.png"), ("merge", 0, "crf", "deep_block.yaml"),
          ("model fit", 0, "rec", "deep.json"), ("library build", 1, "img", "pickled.npy"),
          ("crf fit", 0, "data", "latin1.txt"), ("campaign list", 0, "db", "binary.bin")]


def test_a_sample_as_subprocesses(valid, bad, tmp_path, scaled):
    by_name = {p.name: p for p in bad}
    outdir = tmp_path / "out"
    outdir.mkdir()

    def run(case):
        path, index, slot, name = case
        argv = _argv(TABLE[path][index], slot, by_name[name], valid, outdir)
        r = subprocess.run([sys.executable, "-m", "controller.cli", *argv], capture_output=True, text=True,
                           cwd=REPO, timeout=scaled(60))
        return argv, r, by_name[name]

    with ThreadPoolExecutor(2) as pool:
        for argv, r, f in pool.map(run, SAMPLE):
            _check(argv, r.returncode, r.stdout, r.stderr, f, outdir)
