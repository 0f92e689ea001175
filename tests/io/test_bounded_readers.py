"""The bounded readers of controller/io: every bad file ends in one InputError naming it, before
anything large is allocated; valid files still read; random and mutated bytes never raise
anything else (hypothesis)."""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from badfiles import corpus, npy, npy_header, png, tiff, write_corpus
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.devices.camera import CameraError
from controller.devices.file_camera import FileCamera
from controller.errors import InputError
from controller.geometry.paint_io import read_towers
from controller.imaging.crf_io import load_crf
from controller.io.image_headers import MAX_DECODED_BYTES, MAX_FILE_BYTES, MAX_PIXELS
from controller.io.images import decode_image, read_image
from controller.io.json_files import load_json, nesting_depth, parse_json
from controller.io.yaml_files import load_yaml, parse_yaml
from controller.storage.model_file import read_model

# Valid images for the image readers; the rest of the corpus is bad for every reader.
IMAGES = {"png_named.yaml", "png_named.json", "png_named.csv"}


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> list[Path]:
    return write_corpus(tmp_path_factory.mktemp("bad"))


def test_every_bad_file_is_one_input_error_naming_it(bad, scaled):
    for path in bad:
        if path.name in IMAGES:
            continue
        t0 = time.perf_counter()
        with pytest.raises(InputError) as err:
            read_image(path)
        assert time.perf_counter() - t0 < scaled(2.0), path.name  # refused by its header, not decoded
        msg = str(err.value)
        assert msg.startswith(f"{path}: ") and "\n" not in msg, msg


def test_the_messages_state_the_claim_and_the_limit(bad):
    by_name = {p.name: p for p in bad}
    with pytest.raises(InputError, match=rf"PNG header claims 1000000×1000000 px \(limit {MAX_PIXELS} px\)"):
        read_image(by_name["huge_header.png"])
    with pytest.raises(InputError, match=rf"6000×6000 px × 4 × 2 bytes = 288000000 bytes decoded "
                                         rf"\(limit {MAX_DECODED_BYTES}\)"):
        read_image(by_name["bomb.png"])
    for name in ("huge_header_le.tif", "huge_header_be.tif"):
        with pytest.raises(InputError, match="TIFF header claims 1000000×1000000 px"):
            read_image(by_name[name])
    with pytest.raises(InputError, match="NPY header claims 100000×100000 px"):
        read_image(by_name["huge_header.npy"])
    with pytest.raises(InputError, match="pixel type object"):
        read_image(by_name["pickled.npy"])
    with pytest.raises(InputError, match=r"shape \(2, 3, 4\)"):
        read_image(by_name["three_d.npy"])


def test_valid_images_still_read(tmp_path):
    img8 = (np.arange(12, dtype=np.uint8).reshape(3, 4) * 20)
    img16 = img8.astype(np.uint16) * 250
    flt = img8.astype(np.float32) / 7
    for name, img in (("a.png", img8), ("b.png", img16), ("c.tif", img16), ("d.tiff", flt)):
        assert cv2.imwrite(str(tmp_path / name), img)
        got = read_image(tmp_path / name)
        assert got.dtype == img.dtype and np.array_equal(got, img), name
    (tmp_path / "e.npy").write_bytes(npy(flt))
    assert np.array_equal(read_image(tmp_path / "e.npy"), flt)
    (tmp_path / "f.tif").write_bytes(tiff(4, 3, ">"))  # header only: bounded, then undecodable
    with pytest.raises(InputError, match="not a readable image"):
        read_image(tmp_path / "f.tif")


def test_a_suffix_naming_another_image_format_is_refused(tmp_path):
    assert cv2.imwrite(str(tmp_path / "x.png"), np.zeros((3, 4), np.uint8))
    (tmp_path / "x.npy").write_bytes((tmp_path / "x.png").read_bytes())
    with pytest.raises(InputError, match=r"x.npy: named .npy but holds a PNG image"):
        read_image(tmp_path / "x.npy")
    (tmp_path / "frame").write_bytes((tmp_path / "x.png").read_bytes())  # no suffix: by content
    assert read_image(tmp_path / "frame").shape == (3, 4)


def test_a_file_over_the_size_limit_is_refused_before_it_is_read(tmp_path):
    p = tmp_path / "huge.png"
    with open(p, "wb") as f:  # sparse: costs no disk
        f.write(png(4, 3))
        f.truncate(MAX_FILE_BYTES + 1)
    with pytest.raises(InputError, match=rf"huge.png: {MAX_FILE_BYTES + 1} bytes is too large for an image"):
        read_image(p)


def test_npy_claims_are_checked_before_loading(tmp_path):
    p = tmp_path / "big.npy"
    p.write_bytes(npy_header((9000, 9000), "<f4"))  # 81 Mpx, no data
    with pytest.raises(InputError, match="limit"):
        read_image(p)
    p.write_bytes(npy_header((100, 100), "<f4") + b"\0" * 10)
    with pytest.raises(InputError, match=r"truncated .npy"):
        read_image(p)


def test_json_reader_bounds_depth_size_and_encoding(bad, tmp_path):
    by_name = {p.name: p for p in bad}
    with pytest.raises(InputError, match=r"deep.json: nested 100000 levels deep \(at most 32\)"):
        load_json(by_name["deep.json"])
    with pytest.raises(InputError, match="not a text"):
        load_json(by_name["png_named.json"])
    big = tmp_path / "big.json"
    big.write_text("[" + "0," * 10 + "0]")
    with pytest.raises(InputError, match="too large"):
        load_json(big, max_bytes=10)
    assert nesting_depth('{"a": "[[[{{", "b": [[1], {"c": "\\"]"}]}') == 3
    with pytest.raises(InputError, match=r"x.json: invalid JSON: Expecting"):
        parse_json('{"a": }', "x.json")


def test_yaml_reader_refuses_deep_block_and_flow_nesting(bad):
    by_name = {p.name: p for p in bad}
    for name in ("deep_flow.yaml", "deep_block.yaml"):
        with pytest.raises(InputError, match="nested deeper than 32 levels"):
            load_yaml(by_name[name])
    with pytest.raises(InputError, match="not a text"):
        load_yaml(by_name["png_named.yaml"])


def test_product_readers_go_through_the_bounds(bad, tmp_path):
    by_name = {p.name: p for p in bad}
    with pytest.raises(InputError, match="nested 100000 levels"):
        read_towers(by_name["deep.json"])
    with pytest.raises(InputError, match="nested 100000 levels"):
        read_model(by_name["deep.json"])
    with pytest.raises(InputError, match="deep_block.yaml: line 1: nested deeper"):
        FileCamera(by_name["deep_block.yaml"])
    with pytest.raises(InputError, match="latin1.txt: not a text"):
        load_crf(by_name["latin1.txt"])
    # A manifest pointing at a decompression bomb: the camera refuses the frame, naming it.
    (tmp_path / "m.yaml").write_text(json.dumps({"pairs": [
        {"low": str(by_name["bomb.png"]), "high": str(by_name["bomb.png"]), "exposures": [0.01, 0.02]}]}))
    with pytest.raises(CameraError, match="bomb.png: PNG header claims 6000×6000"):
        FileCamera(tmp_path / "m.yaml").capture()


def _check_image_bytes(data: bytes, name: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / name
        p.write_bytes(data)
        try:
            img = read_image(p)
        except InputError as exc:
            assert str(exc).startswith(str(p)) and "\n" not in str(exc)
        else:
            assert img.ndim == 2 and img.size > 0


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=512), st.sampled_from(["x.png", "x.tif", "x.npy", "x"]))
def test_random_bytes_never_raise_anything_but_input_error(data, name):
    _check_image_bytes(data, name)


_VALID = {
    "x.png": cv2.imencode(".png", np.arange(48, dtype=np.uint8).reshape(6, 8))[1].tobytes(),
    "x.tif": cv2.imencode(".tiff", np.arange(48, dtype=np.uint16).reshape(6, 8))[1].tobytes(),
    "x.npy": npy(np.arange(48, dtype=np.float32).reshape(6, 8)),
    "y.png": png(3, 2, 16, 2),
}


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(_VALID)), st.lists(st.tuples(st.integers(0, 127), st.integers(0, 255)),
                                                min_size=1, max_size=6), st.integers(8, 4096))
def test_mutated_headers_give_input_error_or_an_image(name, edits, keep):
    data = bytearray(_VALID[name])
    for at, value in edits:  # the first 128 bytes hold every header field read
        if at < len(data):
            data[at] = value
    _check_image_bytes(bytes(data[:keep]), name)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet=st.sampled_from(list('[]{}",:0a-\n \\')), max_size=300))
def test_text_parsers_never_raise_anything_but_input_error(text):
    for parse in (parse_json, parse_yaml):
        try:
            parse(text, "t")
        except InputError as exc:
            assert str(exc).startswith("t: ")


def test_corpus_is_small():
    assert sum(len(v) for v in corpus().values()) < 2_000_000  # 1.4 MB, mostly the deep YAML/JSON


def test_decode_image_checks_the_size_the_caller_expects_before_decoding():
    ok, data = cv2.imencode(".png", np.arange(12, dtype=np.uint16).reshape(3, 4))
    assert ok
    assert decode_image(data.tobytes(), "f.png", shape=(3, 4)).shape == (3, 4)
    with pytest.raises(InputError, match=r"f\.png: PNG header claims 4×3 px, expected 4×2"):
        decode_image(data.tobytes(), "f.png", shape=(2, 4))
    # a header claiming the expected size over garbage is still refused by the decoder, naming the file
    with pytest.raises(InputError, match=r"^g\.png: "):
        decode_image(data.tobytes()[:40] + bytes(64), "g.png", shape=(3, 4))
