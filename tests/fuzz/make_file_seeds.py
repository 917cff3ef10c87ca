#!/usr/bin/python3
"""Seeds for fuzz_files (corpus_files/: OctoMap .bt/.ot, PCD, PLY, NPY) and the ROS 1 bag seeds of
fuzz_bag (corpus_bag/*.bag), written here from the formats' specifications with the standard
library only, including the hostile files that crashed terrastride's readers:
- OctoMap bodies of 0xFF bytes and of random bytes after a valid header (OctoMap's recursive
  reader overflowed the stack: SIGSEGV);
- ROS 1 bags whose record header claims a huge length (librosbag allocated it: abort), and other
  lengths and positions that point past the end of the file or of a chunk.
Usage: /usr/bin/python3 tests/fuzz/make_file_seeds.py"""
import bz2
import os
import random
import struct

here = os.path.dirname(os.path.abspath(__file__))
files = os.path.join(here, "corpus_files")
bags = os.path.join(here, "corpus_bag")
os.makedirs(files, exist_ok=True)


def write(folder, name, data):
    with open(os.path.join(folder, name), "wb") as f:
        f.write(data)


# --- OctoMap ------------------------------------------------------------------------------------
def bt_header(size, res=0.05):
    return b"# Octomap OcTree binary file\nid OcTree\nsize %d\nres %g\ndata\n" % (size, res)


def ot_header(size, tree="OcTree", res=0.05):
    return b"# Octomap OcTree file\nid %s\nsize %d\nres %g\ndata\n" % (tree.encode(), size, res)


# A chain from the root down to depth 15 (child 0 an inner node: bits 11), whose last node has two
# occupied leaves at depth 16 (children 0 and 1: bits 01 01): 16 inner nodes + 2 leaves.
chain = b"\x03\x00" * 15 + b"\x0a\x00"
write(files, "chain.bt", bt_header(18) + chain)
write(files, "ff_body.bt", bt_header(18) + b"\xff" * 64)
random.seed(3)
write(files, "random_body.bt", bt_header(18) + bytes(random.randrange(256) for _ in range(256)))
write(files, "deep.bt", bt_header(19) + b"\x03\x00" * 16 + b"\x02\x00")  # inner at depth 16
write(files, "trailing.bt", bt_header(18) + chain + b"\x00\x00")


def ot_chain(node_data):
    # Full format: node data, then a byte with a bit per child (child 0 only, down to depth 16).
    return (node_data + b"\x01") * 16 + node_data + b"\x00"


occupied = struct.pack("<f", 3.5)
write(files, "chain.ot", ot_header(17) + ot_chain(occupied))
write(files, "chain_color.ot", ot_header(17, "ColorOcTree") + ot_chain(occupied + b"\x10\x20\x30"))
write(files, "ff_body.ot", ot_header(17) + b"\xff" * 64)
write(files, "random_body.ot", ot_header(17) + bytes(random.randrange(256) for _ in range(256)))

# --- PCD, PLY, NPY ------------------------------------------------------------------------------
points = [(0.0, 0.0, 0.0), (0.1, 0.0, 0.01), (0.0, 0.1, 0.02), (0.1, 0.1, 0.03)]


def pcd(data_kind, body):
    return (b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            b"WIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 1 1 0 0 0\nPOINTS %d\nDATA %s\n"
            % (len(points), len(points), data_kind) + body)


write(files, "ascii.pcd", pcd(b"ascii", b"".join(b"%g %g %g\n" % p for p in points)))
write(files, "binary.pcd", pcd(b"binary", b"".join(struct.pack("<3f", *p) for p in points)))


def ply(fmt, body):
    return (b"ply\nformat %s 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n" % (fmt, len(points)) + body)


write(files, "ascii.ply", ply(b"ascii", b"".join(b"%g %g %g\n" % p for p in points)))
write(files, "binary.ply",
      ply(b"binary_little_endian", b"".join(struct.pack("<3f", *p) for p in points)))


def npy(descr, fmt):
    header = b"{'descr': '%s', 'fortran_order': False, 'shape': (%d, 3), }" % (descr, len(points))
    header += b" " * ((64 - (10 + len(header) + 1) % 64) % 64) + b"\n"
    return (b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header +
            b"".join(struct.pack(fmt, *p) for p in points))


write(files, "f4.npy", npy(b"<f4", "<3f"))
write(files, "f8.npy", npy(b"<f8", "<3d"))


# --- ROS 1 bags (format 2.0) --------------------------------------------------------------------
def fields(**kv):
    out = b""
    for k, v in kv.items():
        f = k.encode() + b"=" + v
        out += struct.pack("<I", len(f)) + f
    return out


def record(header, data):
    return struct.pack("<I", len(header)) + header + struct.pack("<I", len(data)) + data


u32 = lambda v: struct.pack("<I", v)
u64 = lambda v: struct.pack("<Q", v)
TIME = u32(1700000000) + u32(5)
connection_header = fields(topic=b"/chatter", type=b"std_msgs/String",
                           md5sum=b"992ce8a1687cec8c8bd883ec73ca41d1",
                           message_definition=b"string data\n")
connection = record(fields(op=b"\x07", conn=u32(0), topic=b"/chatter"), connection_header)
message = record(fields(op=b"\x02", conn=u32(0), time=TIME), u32(5) + b"hello")


def ros1_bag(compression=b"none", tweak=None):
    """A bag of one chunk (a connection, a message), its index, as rosbag writes one."""
    plain = connection + message
    packed = {b"none": plain, b"bz2": bz2.compress(plain)}[compression]
    parts = {"chunk_header": fields(op=b"\x05", compression=compression, size=u32(len(plain))),
             "packed": packed, "offset": len(connection)}
    if tweak:
        tweak(parts)
    head_len = 4096  # the bag header record's header and data: padded to 4096 bytes
    chunk_pos = 13 + 8 + head_len
    chunk = record(parts["chunk_header"], parts["packed"])
    index = record(fields(op=b"\x04", ver=u32(1), conn=u32(0), count=u32(1)),
                   TIME + u32(parts["offset"]))
    index_pos = chunk_pos + len(chunk) + len(index)
    chunk_info = record(fields(op=b"\x06", ver=u32(1), chunk_pos=u64(parts.get("chunk_pos", chunk_pos)),
                               start_time=TIME, end_time=TIME, count=u32(1)), u32(0) + u32(1))
    header_fields = fields(op=b"\x03", index_pos=u64(parts.get("index_pos", index_pos)),
                           conn_count=u32(1), chunk_count=u32(1))
    bag_header = record(header_fields, b" " * (head_len - len(header_fields)))
    return b"#ROSBAG V2.0\n" + bag_header + chunk + index + connection + chunk_info


write(bags, "tiny_none.bag", ros1_bag())
write(bags, "tiny_bz2.bag", ros1_bag(b"bz2"))


def huge_header(bag):  # the bag header record's header length: 0xFFFFFFF0
    return bag[:13] + u32(0xFFFFFFF0) + bag[17:]


def set_field(parts, key, value):
    parts[key] = value


good = ros1_bag()
write(bags, "huge_header_len.bag", huge_header(good))
# The chunk record's data length (after its header): past the end of the file.
chunk_at = 13 + 8 + 4096
chunk_header_len = struct.unpack("<I", good[chunk_at:chunk_at + 4])[0]
data_len_at = chunk_at + 4 + chunk_header_len
write(bags, "huge_data_len.bag", good[:data_len_at] + u32(0x7FFFFFFF) + good[data_len_at + 4:])
write(bags, "huge_chunk_size.bag", ros1_bag(b"bz2", lambda p: set_field(
    p, "chunk_header", fields(op=b"\x05", compression=b"bz2", size=u32(0xFFFFFF00)))))
write(bags, "chunk_size_mismatch.bag", ros1_bag(b"none", lambda p: set_field(
    p, "chunk_header", fields(op=b"\x05", compression=b"none", size=u32(1 << 20)))))
write(bags, "index_past_end.bag", ros1_bag(tweak=lambda p: set_field(p, "index_pos", 1 << 40)))
write(bags, "chunk_info_past_end.bag", ros1_bag(tweak=lambda p: set_field(p, "chunk_pos", 1 << 33)))
write(bags, "index_offset_past_chunk.bag", ros1_bag(tweak=lambda p: set_field(p, "offset", 1 << 30)))
# A message record inside the chunk whose header length runs past the chunk.
write(bags, "inner_header_len.bag", ros1_bag(tweak=lambda p: set_field(
    p, "packed", connection + u32(0x7FFFFFFF) + message[4:])))
# A message record inside the chunk whose data length runs past the chunk (librosbag read 4 GB
# past its buffer: SIGSEGV).
write(bags, "inner_data_len.bag", ros1_bag(tweak=lambda p: set_field(
    p, "packed", connection + message[:-13] + u32(0xFFFFFFF0) + message[-9:])))
write(bags, "fake_bz2.bag", ros1_bag(b"bz2", lambda p: set_field(p, "packed", b"BZh9" + b"\x00" * 40)))
