#!/usr/bin/env python3
"""Writes the seed corpus of fuzz_gltf (tests/fuzz/corpus-fuzz_gltf/) from generated levels.

usage: make_corpus_gltf.py GENLEVEL OUTDIR
Each level is generated small (few quads), then made self-contained: .gltf with the .bin
embedded as a base64 data: URI, or packed as .glb (JSON chunk + BIN chunk). The
hand-written tests/data/*.gltf (already self-contained) are copied too.
"""
import base64, glob, json, os, shutil, struct, subprocess, sys, tempfile

LEVELS = [  # (level, params, output format)
    ("cornell", [], "glb"),
    ("cornell", ["emissive=1", "open=1"], "gltf"),
    ("furnace", ["n=1"], "glb"),
    ("plane_point", ["n=1", "size=2"], "gltf"),
    ("sky_plane", ["n=1", "size=2", "uv1=1"], "glb"),
    ("sunroom", [], "gltf"),
    ("hallway", [], "glb"),
    ("two_rooms", ["texel_size=0.1", "glg_spacing=1"], "gltf"),
    ("tjunction", [], "glb"),
    ("mis_edge", [], "gltf"),
    ("grazing", [], "glb"),
]

def pad4(b, fill):
    return b + fill * ((4 - len(b) % 4) % 4)

def main():
    genlevel, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for level, params, fmt in LEVELS:
            base = level + ("_" + "_".join(p.replace("=", "") for p in params) if params else "")
            args = [genlevel, level, "-o", tmp, "--name", base]
            for p in params:
                args += ["--param", p]
            subprocess.run(args, check=True)
            js = json.load(open(os.path.join(tmp, base + ".gltf")))
            binary = open(os.path.join(tmp, base + ".bin"), "rb").read()
            if fmt == "gltf":
                js["buffers"][0]["uri"] = ("data:application/octet-stream;base64," +
                                           base64.b64encode(binary).decode())
                open(os.path.join(out, base + ".gltf"), "w").write(json.dumps(js, indent=1))
            else:
                del js["buffers"][0]["uri"]
                jb = pad4(json.dumps(js, separators=(",", ":")).encode(), b" ")
                bb = pad4(binary, b"\0")
                total = 12 + 8 + len(jb) + 8 + len(bb)
                glb = struct.pack("<4sII", b"glTF", 2, total)
                glb += struct.pack("<I4s", len(jb), b"JSON") + jb
                glb += struct.pack("<I4s", len(bb), b"BIN\0") + bb
                open(os.path.join(out, base + ".glb"), "wb").write(glb)
    src = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data")
    for f in sorted(glob.glob(os.path.join(src, "*.gltf"))):
        shutil.copy(f, os.path.join(out, "data_" + os.path.basename(f)))

if __name__ == "__main__":
    main()
