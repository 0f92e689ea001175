"""The morning reports stay readable: no text of any figure is cut at the image's edge, the
field map names its heliostats, and each heliostat's nights are followed in a trend — on a small
field after its calibration night and two planned nights (cheap optics, in-process drives)."""

from __future__ import annotations

import pytest
import yaml
from matplotlib.figure import Figure
from matplotlib.text import Text

from controller.commands.cheap_night import calibrate_from_truth, run_cheap_night
from controller.reports import field_figures
from controller.reports.campaign import write_report
from controller.reports.night import write_night_report
from controller.storage.db import CampaignStore
from controller.storage.nights import NightBook
from controller.storage.trends import heliostat_trends
from simplant.cheap_night import CheapField, field_data
from tests.calibration.conftest import REPO


@pytest.fixture(scope="module")
def nights(tmp_path_factory):
    """Night 0 (from the truth) and two planned nights of a 6-heliostat, 2-target field."""
    base = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    field = CheapField(field_data(base, 6, 2, 1), tmp_path_factory.mktemp("nights"), speedup=1000.0)
    calibrate_from_truth(field, "field")
    for k in (1, 2):
        run_cheap_night(field, None, f"field/night-{k}", 8 * 3600.0)
    return field


@pytest.fixture
def drawn(monkeypatch):
    """Every PNG figure saved during the test: file name -> [(text, its box in pixels, the
    image's width and height)] of every text drawn into the saved image (the last draw of a
    save is the one written; a tight box is cropped before it)."""
    saved: dict[str, list] = {}
    current: list = []
    real_save, real_draw = Figure.savefig, Text.draw

    def savefig(self, fname, *args, **kw):
        current.clear()
        real_save(self, fname, *args, **kw)
        last = current[-1][0] if current else None
        name = str(fname).rsplit("/", 1)[-1].split(".")[1] + ".png"  # write_atomic's .<stem>.XXXX.png
        saved[name] = [(t, box, size) for r, t, box, size in current if r is last]

    def draw(self, renderer):
        real_draw(self, renderer)
        if self.get_visible() and self.get_text().strip():
            current.append((renderer, self.get_text(), self.get_window_extent(renderer),
                            (renderer.width, renderer.height)))

    monkeypatch.setattr(Figure, "savefig", savefig)
    monkeypatch.setattr(Text, "draw", draw)
    return saved


def _cut(texts) -> list[str]:
    """The texts whose box reaches beyond the image (more than half a pixel)."""
    return [t for t, b, (w, h) in texts if b.x0 < -0.5 or b.y0 < -0.5 or b.x1 > w + 0.5 or b.y1 > h + 0.5]


def test_no_text_of_any_report_figure_is_cut(nights, drawn, tmp_path):
    with CampaignStore(nights.db_path, readonly=True) as store:
        recs = NightBook(store).nights()
        write_night_report(store, tmp_path / "night", recs[-1])
        write_report(store, tmp_path / "night0", store.find_campaign(recs[0].name).id)
    expected = {"passes.png", "field_map.png", "distributions.png", "trend.png", "errors_hist.png",
                "centroids.png", "time_per_heliostat.png", "geometries.png", "daytime.png"}
    assert expected <= set(drawn), sorted(drawn)
    for name, texts in drawn.items():
        assert texts, f"{name}: no text drawn"
        assert not _cut(texts), f"{name}: cut at the edge: {_cut(texts)}"
    lamps = {t.split(" @ ")[0] for t, _, _ in drawn["passes.png"] if " @ " in t}
    assert lamps and lamps <= {s.id for s in nights.cfg.light_sources}


def test_the_field_map_names_every_heliostat_of_a_small_field_and_the_worst_of_a_large(
        nights, drawn, tmp_path, monkeypatch):
    with CampaignStore(nights.db_path, readonly=True) as store:
        rows = NightBook(store).heliostats(NightBook(store).nights()[-1].id)
    ids = {r["heliostat"] for r in rows}
    field_figures.field_map(rows, tmp_path)
    assert ids <= {t for t, _, _ in drawn["field_map.png"]}
    monkeypatch.setattr(field_figures, "LABEL_ALL", 4)  # "large": only the worst named
    monkeypatch.setattr(field_figures, "LABEL_WORST", 3)
    field_figures.field_map(rows, tmp_path)
    worst = sorted(rows, key=lambda r: -r["predicted_rms_mrad"])[:3]
    assert {t for t, _, _ in drawn["field_map.png"]} & ids == {r["heliostat"] for r in worst}


def test_each_heliostat_is_followed_night_by_night(nights):
    with CampaignStore(nights.db_path, readonly=True) as store:
        book = NightBook(store)
        recs = book.nights()
        ids = [h.id for h in nights.cfg.heliostats]
        trends = heliostat_trends(store, ids)
        per_night = {n.index: {r["heliostat"]: r for r in book.heliostats(n.id)} for n in recs}
        camps = {c.id: c.name for c in store.campaigns()}
        for hid in ids:
            assert [p["night"] for p in trends[hid]] == [0, 1, 2], hid
            for p in trends[hid]:
                night = recs[p["night"]]
                looks = [m.error_mrad for m in store.measurements(heliostat_id=hid) if m.iteration == 1
                         and (camps[m.campaign_id] == night.name if night.kind == "calibration"
                              else camps[m.campaign_id].startswith(night.name + "/"))]
                assert p["measured"] == len(looks)
                assert p["first_look_error_mrad"] == pytest.approx(sum(looks) / len(looks))
                row = per_night[p["night"]].get(hid)
                assert p["predicted_rms_mrad"] == (row["predicted_rms_mrad"] if row else None)
                assert p["planned"] == (row["planned"] if row else None)
    # The calibration night's first looks are the uncalibrated error; the planned nights' are far smaller.
    first = [trends[h][0]["first_look_error_mrad"] for h in ids]
    last = [trends[h][-1]["first_look_error_mrad"] for h in ids]
    assert sum(last) < sum(first) / 3


def test_the_trend_of_a_large_field_follows_its_worst_heliostats(nights, drawn, tmp_path, monkeypatch):
    monkeypatch.setattr(field_figures, "TREND_LINES", 2)  # "large": more heliostats than lines
    with CampaignStore(nights.db_path, readonly=True) as store:
        book = NightBook(store)
        recs = book.nights()
        rows = book.heliostats(recs[-1].id)
        assert field_figures.trend(store, recs[-1].index, rows, recs, tmp_path) == "trend.png"
        assert field_figures.trend(store, 0, rows, recs, tmp_path / "first") is None  # one night: no trend
    texts = {t for t, _, _ in drawn["trend.png"]}
    worst = {r["heliostat"] for r in sorted(rows, key=lambda r: -r["predicted_rms_mrad"])[:2]}
    assert texts & {r["heliostat"] for r in rows} == worst
    assert "The 2 heliostats with the largest predicted error tonight" in texts and "field (RMS)" in texts
