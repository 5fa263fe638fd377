#!/usr/bin/env python3
"""Build tiny stub .so files for the CUDA libraries that PyPI's torch links
against but that a CPU-only run never calls (cublas, cudnn, nccl, ...).

`import torch` needs libtorch_python.so -> libtorch_cuda.so, which has
DT_NEEDED entries for ~12 NVIDIA libraries (~4.7 GB as wheels). None of their
functions run when everything stays on the CPU, so each missing library is
replaced by a stub with the same SONAME and symbol versions, exporting every
symbol torch imports from it (functions return a non-zero error code).

Usage: make_cuda_stubs.py TORCH_PKG_DIR   (e.g. .../site-packages/torch)
Stubs go into TORCH_PKG_DIR/lib, which is the LAST entry of torch's RPATH, so
real nvidia-* wheels, if installed later, still win. Idempotent.
"""
import collections
import os
import re
import subprocess
import sys
import tempfile

torch_dir = sys.argv[1]
lib_dir = os.path.join(torch_dir, "lib")
sp = os.path.dirname(torch_dir)

elves = []
for root, _, files in os.walk(torch_dir):
    for f in files:
        if re.search(r"\.so(\.\d+)*$", f):
            elves.append(os.path.join(root, f))

def needed(path):
    out = subprocess.run(["readelf", "-d", path], capture_output=True, text=True).stdout
    return re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", out)

def resolvable(soname):
    if os.path.exists(os.path.join(lib_dir, soname)):
        return True
    for d in ("nvidia/cu13/lib", "nvidia/cudnn/lib", "nvidia/nvshmem/lib",
              "nvidia/nccl/lib", "nvidia/cusparselt/lib"):
        if os.path.exists(os.path.join(sp, d, soname)):
            return True
    r = subprocess.run(["/sbin/ldconfig", "-p"], capture_output=True, text=True).stdout
    return re.search(r"^\s*" + re.escape(soname) + r"\s", r, re.M) is not None

# Libraries only dlopen'ed lazily by torch (never at import): leave alone.
SKIP = {"libcuda.so.1"}
own = {os.path.basename(e) for e in elves}
missing = set()
for e in elves:
    for n in needed(e):
        if n not in own and n not in SKIP and not resolvable(n):
            missing.add(n)
# libcaffe2_nvrtc / libtorch_cuda_linalg are dlopen'ed lazily, but stubbing
# their needs is harmless and keeps the set closed.

syms = collections.defaultdict(lambda: collections.defaultdict(dict))  # soname -> version -> name -> kind
for e in elves:
    out = subprocess.run(["readelf", "--dyn-syms", "-W", e], capture_output=True, text=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) < 8 or parts[6] != "UND":
            continue
        m = re.match(r"([^@]+)@([^ ]+)", parts[7])
        if not m:
            continue
        name, ver = m.group(1), m.group(2)
        ver = re.sub(r"\s*\(\d+\)$", "", ver)
        if ver in missing:
            syms[ver][ver][name] = parts[3]

# Map version names to sonames through the version-needs tables (covers
# version names that differ from the soname).
for e in elves:
    out = subprocess.run(["readelf", "-V", "-W", e], capture_output=True, text=True).stdout
    cur = None
    vmap = {}
    for line in out.splitlines():
        m = re.search(r"File: (\S+)\s+Cnt:", line)
        if m:
            cur = m.group(1)
            continue
        m = re.search(r"Name: (\S+)\s+Flags:.*Version: (\d+)", line)
        if m and cur in missing:
            vmap[m.group(1)] = cur
    if not vmap:
        continue
    dyn = subprocess.run(["readelf", "--dyn-syms", "-W", e], capture_output=True, text=True).stdout
    for line in dyn.splitlines():
        parts = line.split()
        if len(parts) < 8 or parts[6] != "UND":
            continue
        m = re.match(r"([^@]+)@(\S+)", parts[7])
        if m and m.group(2) in vmap:
            syms[vmap[m.group(2)]][m.group(2)][m.group(1)] = parts[3]

# Unversioned imports (nccl, curand, cufile, cusparseLt, part of nvshmem)
# carry no library name: attribute them by prefix.
PREFIX = {"nccl": "libnccl.so.2", "curand": "libcurand.so.10", "cuFile": "libcufile.so.0",
          "cusparseLt": "libcusparseLt.so.0", "nvshmem": "libnvshmem_host.so.3"}
for e in elves:
    out = subprocess.run(["readelf", "--dyn-syms", "-W", e], capture_output=True, text=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) < 8 or parts[6] != "UND" or "@" in parts[7]:
            continue
        for p, so in PREFIX.items():
            if parts[7].startswith(p) and so in missing:
                vers = [v for v in syms[so] if v != "_unversioned"]
                syms[so][vers[0] if vers else "_unversioned"][parts[7]] = parts[3]

made = []
with tempfile.TemporaryDirectory() as tmp:
    for so in sorted(missing):
        c = ["/* stub for %s: never called on CPU */" % so]
        for ver, names in sorted(syms[so].items()):
            for n, kind in sorted(names.items()):
                if kind == "OBJECT":
                    c.append("char %s[256] = {0};" % n)
                else:
                    c.append("int %s(void) { return 999; }" % n)
        cpath = os.path.join(tmp, so + ".c")
        vpath = os.path.join(tmp, so + ".map")
        open(cpath, "w").write("\n".join(c) + "\n")
        vlines = []
        for ver, names in sorted(syms[so].items()):
            if ver == "_unversioned":
                continue
            vlines.append("%s {\n  global:\n%s\n  local: *;\n};" % (ver, "\n".join("    %s;" % n for n in sorted(names))))
        open(vpath, "w").write("\n".join(vlines) + "\n" if vlines else "")
        out = os.path.join(lib_dir, so)
        cmd = ["gcc", "-shared", "-fPIC", "-O0", "-w", "-o", out, "-Wl,-soname," + so, cpath]
        if vlines:
            cmd.append("-Wl,--version-script=" + vpath)
        subprocess.run(cmd, check=True)
        made.append((so, sum(len(v) for v in syms[so].values())))

for so, n in made:
    print("stub %-24s %5d symbols" % (so, n))
if not made:
    print("no missing CUDA libraries")
