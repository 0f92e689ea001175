"""Write vectors.h (C arrays) from firmware_proto/vectors/frames.json: gen_vectors.py JSON OUT."""

import json
import sys


def _bytes(name: str, hexstr: str) -> str:
    data = bytes.fromhex(hexstr)
    body = ", ".join(f"0x{b:02X}" for b in data) or "0"
    return f"static const uint8_t {name}[] = {{{body}}};\n"


def header(doc: dict) -> str:
    out = ["/* generated from frames.json; do not edit */\n"]
    crcs, valid, invalid = [], [], []
    for i, c in enumerate(doc["crc"]["checks"]):
        out.append(_bytes(f"crc_{i}", c["data"]))
        crcs.append(f"{{crc_{i}, {len(c['data']) // 2}, 0x{c['crc']:04X}}}")
    for i, v in enumerate(doc["valid"]):
        out.append(_bytes(f"vp_{i}", v["payload"]) + _bytes(f"vw_{i}", v["wire"]))
        valid.append(f"{{\"{v['name']}\", {v['address']}, {v['seq']}, {v['command']}, vp_{i}, "
                     f"{len(v['payload']) // 2}, vw_{i}, {len(v['wire']) // 2}}}")
    for i, v in enumerate(doc["invalid"]):
        out.append(_bytes(f"iw_{i}", v["wire"]))
        invalid.append(f"{{\"{v['name']}\", iw_{i}, {len(v['wire']) // 2}, \"{v['reason']}\"}}")
    out.append("static const crc_vector CRC_VECTORS[] = {" + ", ".join(crcs) + "};\n")
    out.append("static const valid_vector VALID[] = {" + ",\n  ".join(valid) + "};\n")
    out.append("static const invalid_vector INVALID[] = {" + ",\n  ".join(invalid) + "};\n")
    for name, items in (("N_CRC", crcs), ("N_VALID", valid), ("N_INVALID", invalid)):
        out.append(f"#define {name} {len(items)}u\n")
    return "".join(out)


if __name__ == "__main__":
    with open(sys.argv[1], encoding="utf-8") as f:
        text = header(json.load(f))
    with open(sys.argv[2], "w", encoding="utf-8") as f:
        f.write(text)
