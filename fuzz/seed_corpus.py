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
# c_api: programs of C API calls (fuzz_targets/c_api.rs): every vector's
# frames received in order (opcode 0), and a server program that makes a
# table, sets points, and encodes a delta and a keyframe.
c_api = root / "corpus" / "c_api"
c_api.mkdir(parents=True, exist_ok=True)
for v in vectors:
    frames = [bytes.fromhex(l.split(" ", 1)[1]) for l in v.read_text().splitlines() if l.startswith("frame ")]
    program = b"".join(b"\x00" + struct.pack("<H", len(f)) + f for f in frames if len(f) < 65536)
    (c_api / v.stem).write_bytes(program + b"\x01\x01\x00\x00\x00\x00\x40\x00\x02\x10\x05\x40")
f3 = lambda *v: struct.pack("<3f", *v)
table = b"\x06" + f3(-1, -1, -1) + f3(0.25, 0.25, 0.25) + bytes([8, 8, 8, 6, 8, 7, 0, 1]) + struct.pack("<H", 256) + struct.pack("<3f", 0.2, 0.1, 0.7) + b"\x01"
points = b"".join(b"\x07" + struct.pack("<H", i) + f3(0.1 * (i % 9) - 0.4, 0.05 * i - 0.5, 0.2) + f3(0, 1, 0) + struct.pack("<f", (i % 10) / 10) + bytes([i % 2]) for i in range(20))
server = table + points + b"\x08\x02\x01\x00\x00\x00\x00" + b"\x08\x00" + b"\x09\x00" + b"\x0a\xff\xff" + b"\x08\x01" + b"\x09\x01" + b"\x0a\x10\x00" + b"\x0a\xff\xff"
(c_api / "server").write_bytes(server)
# moq_follow: each MoQ vector (spec/vectors/moq) as a program of the
# target's operations (fuzz_targets/moq_follow.rs).
moq = root / "corpus" / "moq_follow"
moq.mkdir(parents=True, exist_ok=True)
for v in sorted((root.parent / "spec" / "vectors" / "moq").glob("*.txt")):
    program = bytearray()
    for line in v.read_text().splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "catalog" and len(bytes.fromhex(words[1])) < 256:
            body = bytes.fromhex(words[1])
            program += b"\x00" + bytes([len(body)]) + body
        elif words[0] == "frame":
            body = bytes.fromhex(words[3])
            if len(body) < 65536:
                program += b"\x01" + struct.pack("<HBH", int(words[1]) % 65536, int(words[2]) % 256, len(body)) + body
        elif words[0] == "digest" and len(bytes.fromhex(words[1])) < 256:
            body = bytes.fromhex(words[1])
            program += b"\x02" + bytes([len(body)]) + body
        elif words[0] == "restart":
            program += b"\x03"
    (moq / v.stem).write_bytes(bytes(program))
