"""An independent reader of the rosbag2 bags the recorder writes (the tests' reference)."""

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore


def read_bag(path, decoded=None):
    """{topic: (type, [(bag stamp ns, message)])} through rosbags' reader, each message of the ``decoded`` topics
    (default: all) decoded with the message definitions stored in the bag (an empty typestore to start from), the
    others' kept as their CDR bytes."""
    out, store = {}, get_typestore(Stores.EMPTY)
    with Reader(path) as reader:
        for connection in reader.connections:
            store.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
            out[connection.topic] = (connection.msgtype, [])
        for connection, stamp, data in reader.messages():
            if decoded is None or connection.topic in decoded:
                data = store.deserialize_cdr(data, connection.msgtype)
            out[connection.topic][1].append((stamp, data))
    return out
