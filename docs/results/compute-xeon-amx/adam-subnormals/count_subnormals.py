"""Count the subnormal values among an AdamW checkpoint's moments.

    python3 count_subnormals.py RUN_DIR/checkpoints/learner/optimizer.safetensors

Prints the number of moments, how many are subnormal and how many are zero, then the
tensors holding the most subnormal values (name, subnormal, length). Standard library only.
"""
import array
import json
import struct
import sys

data = open(sys.argv[1], "rb").read()
header_len = struct.unpack("<Q", data[:8])[0]
header = json.loads(data[8 : 8 + header_len])
base = 8 + header_len
total = subnormal = zero = 0
per_tensor = {}
for name, info in header.items():
    if name == "__metadata__":
        continue
    assert info["dtype"] == "F32", f"{name}: {info['dtype']}"
    start, end = info["data_offsets"]
    bits = array.array("I")
    bits.frombytes(data[base + start : base + end])
    sub = sum(1 for b in bits if b & 0x7F800000 == 0 and b & 0x7FFFFFFF != 0)
    total += len(bits)
    subnormal += sub
    zero += sum(1 for b in bits if b & 0x7FFFFFFF == 0)
    if sub:
        per_tensor[name] = (sub, len(bits))
print(f"moments {total:,}, subnormal {subnormal:,} ({100 * subnormal / total:.2f} %), zero {zero:,}")
for name, (sub, n) in sorted(per_tensor.items(), key=lambda kv: -kv[1][0])[:10]:
    print(f"  {name}: {sub:,} of {n:,}")
