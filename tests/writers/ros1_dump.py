"""Run by Debian's ``/usr/bin/python3`` with its ``python3-rosbag`` (ROS 1's own reader, not rosbags):
``python3 ros1_dump.py BAG OUTDIR`` writes ``OUTDIR/index.json`` (the bag's topics with their types
and message counts as ``rosbag`` reports them, and each PointCloud2's header, layout and bag time)
and ``OUTDIR/cloud_K.bin`` (the K-th PointCloud2's ``data``). Standard library and rosbag only: the
system Python has no NumPy. The messages are deserialised by rosbag from the definitions the bag
carries (genpy), as ``rosbag play`` would."""

import json
import os
import sys

import rosbag


def main(bag_path, out_dir):
    index = {"topics": {}, "clouds": [], "md5": {}}
    with rosbag.Bag(bag_path) as bag:
        info = bag.get_type_and_topic_info()
        index["md5"] = dict(info.msg_types)
        for topic, t in info.topics.items():
            index["topics"][topic] = [t.msg_type, t.message_count]
        for topic, msg, t in bag.read_messages():
            if msg._type != "sensor_msgs/PointCloud2":
                continue
            k = len(index["clouds"])
            with open(os.path.join(out_dir, "cloud_%d.bin" % k), "wb") as fh:
                fh.write(bytes(msg.data))
            index["clouds"].append({
                "topic": topic, "bag_time_ns": t.to_nsec(), "stamp_ns": msg.header.stamp.to_nsec(),
                "seq": msg.header.seq, "frame_id": msg.header.frame_id, "height": msg.height, "width": msg.width,
                "point_step": msg.point_step, "row_step": msg.row_step, "is_dense": bool(msg.is_dense),
                "fields": [[f.name, f.offset, f.datatype, f.count] for f in msg.fields]})
    with open(os.path.join(out_dir, "index.json"), "w") as fh:
        json.dump(index, fh)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
