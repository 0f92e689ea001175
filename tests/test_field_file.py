"""A field in its own file (``field:`` section, a CSV of heliostats; issue 40 item 7): it loads
as its inline twin does, a bad row or a bad file ends in one line naming file, line and column
(exit 2), and a 10,000-heliostat field loads."""

from __future__ import annotations

import hashlib
import json
import sys
import time
from pathlib import Path

import pytest
import yaml

from controller.config import config_sha256, load_config
from controller.errors import ConfigError
from simplant.cheap_night import field_data, write_config
from tests.conftest import run_cli, scaled_s

sys.path.insert(0, str(Path(__file__).parent / "io"))

from badfiles import write_corpus  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "configs" / "demo.yaml"
SUN = ["sun", "--time", "2026-06-21T12:00:00Z", "--config"]  # a command that only loads the config


def _demo() -> dict:
    return json.loads(json.dumps(yaml.safe_load(DEMO.read_text())))


@pytest.fixture
def field(tmp_path) -> Path:
    """The demo plant written as a large plant keeps it: plant.yaml and plant.csv."""
    path = tmp_path / "plant.yaml"
    write_config(_demo(), path)
    return path


def test_the_field_file_gives_the_inline_heliostats_and_its_hash_covers_the_file(field):
    cfg = load_config(field)
    assert cfg.heliostats == load_config(DEMO).heliostats
    assert cfg.field is not None and cfg.field.file == "plant.csv"
    before = config_sha256(field)
    assert before == hashlib.sha256(field.read_bytes() + field.with_suffix(".csv").read_bytes()).hexdigest()
    csv = field.with_suffix(".csv")
    csv.write_text(csv.read_text().replace("H18,22.5,70.0", "H18,22.6,70.0"))
    assert config_sha256(field) != before
    assert load_config(field).heliostat("H18").position_enu_m[0] == 22.6


# (edit of the CSV text, line, column, rule fragment)
ROWS = [
    (("H03,-4.5,40.0", "H03,east,40.0"), "line 4, column east_m", "valid number"),
    (("H03,-4.5,40.0,2.0", "H03,-4.5,40.0,2500"), "line 4, column up_m", "less than or equal to 2000"),
    (("H03,-4.5,40.0", "H03,nan,40.0"), "line 4, column east_m", "finite number"),
    (("H03,", "H02,"), "line 4, column id", "duplicate id 'H02' (first at line 3)"),
    (("design1,bus1,3,", "design1,bus1,2,"), "line 4, column station", "'H02' (line 3) and 'H03' share"),
    (("design1,bus1,3,", "design1,bus1,300,"), "line 4, column station", "1 … 247"),
    (("design1,bus1,3,", "design1,bus1,three,"), "line 4, column station", "not a whole number"),
    (("design1,bus1,3,", "design1,bus9,3,"), "line 4, column bus", "'bus9' is not a name of field.buses"),
    (("design1,bus1,3,", "design2,bus1,3,"), "line 4, column kinematics", "not a name of field.kinematics"),
    (("bus1,3,49.0", "bus1,3,-49.0"), "line 4, column focal_length_m", "greater than 0"),
    (("station,", "stations,"), "line 1, column stations", "unknown column"),
    ((",station,", ","), "line 1, column station", "required column is missing"),
    (("H03,-4.5,", "H03,"), "line 4", "7 fields, the header has 8"),
    (("H03,-4.5,", '"H03,-4.5,'), "line 4", "a quoted cell runs over several lines"),
]


@pytest.mark.parametrize("edit,where,rule", ROWS, ids=[r[1] + ": " + r[2] for r in ROWS])
def test_a_bad_row_is_refused_naming_file_line_and_column(field, edit, where, rule):
    csv = field.with_suffix(".csv")
    text = csv.read_text()
    assert edit[0] in text
    csv.write_text(text.replace(edit[0], edit[1], 1))
    code, out, err = run_cli([*SUN, str(field)])
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{csv}: {where}: " in err and rule in err, err


def test_field_section_errors_name_the_key(field):
    text = field.read_text()
    for old, new, message in (
            ("kind: serial", "kind: serail", "field.buses.bus1: Input tag 'serail'"),
            ("file: plant.csv", "file: nowhere.csv", "nowhere.csv: cannot read field file"),
            ("increment: 154166.6667", "increment: -1", "field.kinematics.design1.axes.azimuth.increment")):
        field.write_text(text.replace(old, new, 1))
        with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace("(", r"\(")):
            load_config(field)
    both = yaml.safe_load(text)
    both["heliostats"] = _demo()["heliostats"]
    field.write_text(yaml.safe_dump(both))
    with pytest.raises(ConfigError, match="heliostats: given both inline and in field.file"):
        load_config(field)


def test_every_bad_file_as_field_file_exits_2_with_one_line(field, tmp_path):
    text = field.read_text()
    for bad in write_corpus(tmp_path / "bad"):  # none of them is a field file
        field.write_text(text.replace("file: plant.csv", f"file: {bad}"))
        t = time.monotonic()
        code, out, err = run_cli([*SUN, str(field)])
        assert time.monotonic() - t < scaled_s(10), bad.name
        assert code == 2 and out == "" and "Traceback" not in err, (bad.name, err)
        assert len(err.splitlines()) == 1 and bad.name in err, (bad.name, err)


def test_a_large_yaml_is_refused_pointing_at_the_field_file(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text(DEMO.read_text() + "#" * (9 << 20) + "\n")
    with pytest.raises(ConfigError, match="too large.*heliostats go in a field file"):
        load_config(big)


def test_a_field_of_10000_heliostats_loads(tmp_path):
    data = field_data(_demo(), 10_000, 3)
    path = tmp_path / "field.yaml"
    write_config(data, path)
    assert path.stat().st_size < 100_000 and path.with_suffix(".csv").stat().st_size < 1 << 20
    cfg = load_config(path)
    assert len(cfg.heliostats) == 10_000
    last, row = cfg.heliostat("F09999"), data["heliostats"][9998]
    assert last.position_enu_m == tuple(row["position_enu_m"])
    assert last.mirror.focal_length_m == row["mirror"]["focal_length_m"]
