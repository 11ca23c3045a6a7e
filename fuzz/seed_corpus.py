#!/usr/bin/env python3
"""Seeds the fuzz corpora from spec/vectors: every frame for decode_frame,
every vector's frame stream (u16-length-prefixed) for mirror_apply."""
import pathlib, struct

root = pathlib.Path(__file__).resolve().parent
vectors = sorted((root.parent / "spec" / "vectors").glob("*.txt"))
single = root / "corpus" / "decode_frame"
differential = root / "corpus" / "decode_differential"
differential.mkdir(parents=True, exist_ok=True)
stream = root / "corpus" / "mirror_apply"
single.mkdir(parents=True, exist_ok=True)
stream.mkdir(parents=True, exist_ok=True)
for v in vectors:
    frames = [bytes.fromhex(l.split(" ", 1)[1]) for l in v.read_text().splitlines() if l.startswith("frame ")]
    for i, f in enumerate(frames):
        (single / f"{v.stem}-{i}").write_bytes(f)
        # Odd first byte: the frame as it is (decode_differential).
        (differential / f"{v.stem}-{i}").write_bytes(b"\x01" + f)
    (stream / v.stem).write_bytes(b"".join(struct.pack("<H", len(f)) + f for f in frames if len(f) < 65536))
models = root / "corpus" / "gltf_import"
models.mkdir(parents=True, exist_ok=True)
for m in sorted((root.parent / "psao-scene" / "tests" / "data").glob("*.gl*")):
    (models / m.name).write_bytes(m.read_bytes())
# session_bytes: a selector byte, then control messages (spec/session.md
# section 8 examples) or frame records of the vectors' frames.
session = root / "corpus" / "session_bytes"
session.mkdir(parents=True, exist_ok=True)
spec = (root.parent / "spec" / "session.md").read_text().splitlines()
examples, block = [], None
for line in spec:
    if line.startswith("```hex "):
        block = bytearray()
    elif line.startswith("```") and block is not None:
        examples.append(bytes(block))
        block = None
    elif block is not None:
        block.extend(bytes.fromhex(line))
for i, e in enumerate(examples):
    (session / f"server-{i}").write_bytes(b"\x00" + examples[0] + e)
    (session / f"client-{i}").write_bytes(b"\x01" + e)
for v in vectors[:20]:
    frames = [bytes.fromhex(l.split(" ", 1)[1]) for l in v.read_text().splitlines() if l.startswith("frame ")]
    recs = b"".join(struct.pack("<I", len(f)) + f for f in frames)
    (session / f"frames-{v.stem}").write_bytes(b"\x02" + recs)
    cap = b"PSAOCAP1\x01\x00\x00\x00\x00\x00\x00\x00" + b"".join(
        struct.pack("<QI", 10 * k, len(f)) + f for k, f in enumerate(frames))
    (session / f"capture-{v.stem}").write_bytes(b"\x03" + cap)
print(f"seeded {len(vectors)} vectors, the glTF test models and {len(examples)} session examples")
