#!/usr/bin/env python3
"""Seeds the fuzz corpora from spec/vectors: every frame for decode_frame,
every vector's frame stream (u16-length-prefixed) for mirror_apply."""
import pathlib, struct

root = pathlib.Path(__file__).resolve().parent
vectors = sorted((root.parent / "spec" / "vectors").glob("*.txt"))
single = root / "corpus" / "decode_frame"
stream = root / "corpus" / "mirror_apply"
single.mkdir(parents=True, exist_ok=True)
stream.mkdir(parents=True, exist_ok=True)
for v in vectors:
    frames = [bytes.fromhex(l.split(" ", 1)[1]) for l in v.read_text().splitlines() if l.startswith("frame ")]
    for i, f in enumerate(frames):
        (single / f"{v.stem}-{i}").write_bytes(f)
    (stream / v.stem).write_bytes(b"".join(struct.pack("<H", len(f)) + f for f in frames if len(f) < 65536))
models = root / "corpus" / "gltf_import"
models.mkdir(parents=True, exist_ok=True)
for m in sorted((root.parent / "psao-scene" / "tests" / "data").glob("*.gl*")):
    (models / m.name).write_bytes(m.read_bytes())
print(f"seeded {len(vectors)} vectors and the glTF test models")
