#!/usr/bin/python3
"""Seeds for fuzz_bag (corpus_bag/) besides those of
tests/fixtures/bags/generator/fuzz_seeds.mjs: a tiny rosbag2 .db3 (rosbag2's schema with Python's
sqlite3, holding the CDR bytes of corpus_bag/cloud.cdr and tf.cdr) and the same messages in ROS 1
serialisation (Debian's python3-sensor-msgs / python3-tf2-msgs). Run with Debian's Python after
fuzz_seeds.mjs:  /usr/bin/python3 tests/fuzz/make_bag_seeds.py"""
import io
import math
import os
import sqlite3
import struct

here = os.path.dirname(os.path.abspath(__file__))
out = os.path.join(here, "corpus_bag")
cloud_cdr = open(os.path.join(out, "cloud.cdr"), "rb").read()
tf_cdr = open(os.path.join(out, "tf.cdr"), "rb").read()

path = os.path.join(out, "tiny.db3")
if os.path.exists(path):
    os.remove(path)
db = sqlite3.connect(path)
db.executescript(
    """
    PRAGMA page_size = 512;
    CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
    CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                        serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
    CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                          timestamp INTEGER NOT NULL, data BLOB NOT NULL);
    INSERT INTO schema VALUES (3, 'humble');
    INSERT INTO topics VALUES (1, '/tf', 'tf2_msgs/msg/TFMessage', 'cdr', '');
    INSERT INTO topics VALUES (2, '/points', 'sensor_msgs/msg/PointCloud2', 'cdr', '');
    """
)
t0 = 1700000000 * 10**9
db.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?, ?)", (t0, tf_cdr))
db.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (2, ?, ?)", (t0 + 1, cloud_cdr))
db.commit()
db.execute("VACUUM")
db.close()

from geometry_msgs.msg import TransformStamped  # noqa: E402 (Debian's ROS 1 Python messages)
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
import rospy  # noqa: E402

cloud = PointCloud2()
cloud.header.stamp = rospy.Time(1700000000, 100000000)
cloud.header.frame_id = "/lidar"
cloud.height, cloud.width = 1, 3
cloud.fields = [PointField(n, 8 * k, PointField.FLOAT64, 1) for k, n in enumerate("xyz")]
cloud.is_bigendian, cloud.point_step, cloud.row_step = False, 24, 72
cloud.data = struct.pack("<9d", 1, 0, -1, math.nan, 0, 0, 1.1, 0.1, -1)
t = TransformStamped()
t.header.stamp = rospy.Time(1700000000, 100000000)
t.header.frame_id, t.child_frame_id = "odom", "lidar"
t.transform.translation.z = 1.0
t.transform.rotation.w = 1.0
for name, msg in (("cloud.ros1", cloud), ("tf.ros1", TFMessage([t]))):
    buf = io.BytesIO()
    msg.serialize(buf)
    open(os.path.join(out, name), "wb").write(buf.getvalue())
print("wrote", sorted(os.listdir(out)))
