#!/usr/bin/python3
"""Each kind of bad message gets an error reply from a running service and
changes nothing; newer cameras supersede queued ones; the job keeps serving.
    service_bad_requests.py ENDPOINT      (POINTILLIST_PYTHON names the generated modules)
"""
import os
import sys
import time

import numpy as np
import zmq

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                "clients", "python"))
from pointillist_client import PointillistClient, ServiceError, pb  # noqa: E402

endpoint = sys.argv[1]
failures = []


def check(condition, what):
    print(("ok   " if condition else "FAIL ") + what, flush=True)
    if not condition:
        failures.append(what)


def expect_error(reply, code, what):
    got = pb.ErrorCode.Name(reply.error.code) if reply.HasField("error") else "no error"
    check(reply.HasField("error") and reply.error.code == code,
          f"{what}: {pb.ErrorCode.Name(code)} (got {got}: {reply.error.message})")


def expect_call_error(call, code, what):
    try:
        call()
    except ServiceError as error:
        check(error.code == code, f"{what}: {pb.ErrorCode.Name(code)} (got {error})")
        return
    check(False, f"{what}: {pb.ErrorCode.Name(code)} (got a normal reply)")


client = PointillistClient(endpoint, name="bad-requests")
info = client.info()
stats_before = client.stats()


def request(**body):
    return pb.Request(version=pb.SERVICE_VERSION_CURRENT, client_id=client.client_id,
                      request_id=4242, **body)


expect_error(client.send_raw(b"\xff\xfe not a protobuf \x00\x01"), pb.ERROR_MALFORMED,
             "garbage bytes")
expect_error(client.send_raw(b"x" * (100 * 1024)), pb.ERROR_TOO_LARGE, "100 KiB message")
unknown = request(info=pb.InfoRequest())
unknown.ClearField("info")
expect_error(client.send_raw(unknown.SerializeToString() + b"\x9a\x06\x00"),
             pb.ERROR_UNKNOWN_REQUEST, "unknown request body")
expect_error(client.send_raw(request(attach=pb.AttachRequest()).SerializeToString()),
             pb.ERROR_UNKNOWN_REQUEST, "attach on the control socket")
wrong_version = request(info=pb.InfoRequest())
wrong_version.version = 99
expect_error(client.send_raw(wrong_version.SerializeToString()), pb.ERROR_VERSION_MISMATCH,
             "protocol version 99")
stranger = request(info=pb.InfoRequest())
stranger.client_id = "not-a-client"
expect_error(client.send_raw(stranger.SerializeToString()), pb.ERROR_UNKNOWN_CLIENT,
             "unknown client id")
same_point = client.camera((1, 1, 1), (1, 1, 1))
expect_error(client.send_raw(request(render=pb.RenderRequest(camera=same_point))
                             .SerializeToString()), pb.ERROR_INVALID_ARGUMENT,
             "camera with eye == target")
expect_error(client.send_raw(request(path=pb.PathRequest(builtin="/etc/passwd", frames=2))
                             .SerializeToString()), pb.ERROR_INVALID_ARGUMENT,
             "a file name as camera path")
huge = request(render=pb.RenderRequest(camera=client.camera((0, 0, 1), (1, 1, 0)),
                                       format=pb.FrameFormat(width=100000, height=100000)))
expect_error(client.send_raw(huge.SerializeToString()), pb.ERROR_INVALID_ARGUMENT,
             "a 100000x100000 frame")
expect_call_error(lambda: client.call(pb.Request(set_options=pb.SetOptionsRequest(mode="bogus"))),
                  pb.ERROR_INVALID_ARGUMENT, "an unknown render mode")
expect_call_error(lambda: client.call(pb.Request(set_options=pb.SetOptionsRequest(
    mode="splats", scheduler="fastest"))), pb.ERROR_INVALID_ARGUMENT, "an unknown scheduler")
expect_call_error(lambda: client.call(pb.Request(set_options=pb.SetOptionsRequest(
    lod_pixels=-1.0))), pb.ERROR_INVALID_ARGUMENT, "a negative level of detail")
expect_call_error(lambda: client.call(pb.Request(set_options=pb.SetOptionsRequest(
    mode="m" * 100))), pb.ERROR_INVALID_ARGUMENT, "a 100-byte mode name")
# The job draws with the cpu renderer: splats are out of its reach.
expect_call_error(lambda: client.call(pb.Request(set_options=pb.SetOptionsRequest(
    mode="splats", lod_pixels=2.0))), pb.ERROR_NOT_CHANGEABLE,
    "a mode the job's renderer cannot draw")
unchanged = client.call(pb.Request(set_options=pb.SetOptionsRequest())).options
check(unchanged.mode == "points" and unchanged.lod_pixels == info.lod_pixels and
      unchanged.scheduler == info.scheduler,
      f"refused options changed nothing ({unchanged.mode}, {unchanged.lod_pixels}, "
      f"{unchanged.scheduler})")

# Many message parts: refused with a reply.
client.control.send_multipart([b"", b"a", b"b", b"c"])
reply = pb.Reply.FromString(client.control.recv_multipart()[-1])
expect_error(reply, pb.ERROR_MALFORMED, "a request in four parts")

# A client that hello'd but never attached its stream cannot render.
raw = zmq.Context.instance().socket(zmq.REQ)
raw.setsockopt(zmq.LINGER, 0)
raw.connect(endpoint)
raw.send(pb.Request(version=pb.SERVICE_VERSION_CURRENT, request_id=1,
                    hello=pb.Hello(client_name="plain REQ")).SerializeToString())
check(raw.poll(10000), "a plain REQ socket gets a hello reply")
lonely = pb.Reply.FromString(raw.recv()).hello.client_id
raw.send(pb.Request(version=pb.SERVICE_VERSION_CURRENT, client_id=lonely, request_id=2,
                    render=pb.RenderRequest(camera=client.camera((0, 0, 1), (1, 1, 0))))
         .SerializeToString())
check(raw.poll(10000), "REQ render answered")
expect_error(pb.Reply.FromString(raw.recv()), pb.ERROR_UNKNOWN_CLIENT, "render before attach")

# Over ZMQ_MAXMSGSIZE (1 MiB): libzmq drops that connection unread; no reply,
# and the service is not disturbed.
big = zmq.Context.instance().socket(zmq.DEALER)
big.setsockopt(zmq.LINGER, 0)
big.connect(endpoint)
big.send_multipart([b"", b"y" * (2 << 20)])
check(not big.poll(2000), "a 2 MiB message is dropped unanswered")
big.close()

stats = client.stats()
check(stats.errors >= stats_before.errors + 16,
      f"the errors are counted ({stats.errors - stats_before.errors} new)")
check(stats.frames_rendered == stats_before.frames_rendered and stats.queued == 0,
      "no frame was rendered or queued by the bad requests")

# A live option: this client's frames at another size.
fmt = client.call(pb.Request(set_options=pb.SetOptionsRequest(
    format=pb.FrameFormat(width=320, height=180)))).options.format
check(fmt.width == 320 and fmt.height == 180, "frame size changed live for this client")
lo = np.array([info.bounds_min.x, info.bounds_min.y, info.bounds_min.z])
hi = np.array([info.bounds_max.x, info.bounds_max.y, info.bounds_max.z])
centre = (lo + hi) / 2
eye = centre + (hi - lo) * np.array([0.9, -0.9, 0.6])
array = client.render_array(tuple(eye), tuple(centre))
check(array.shape == (180, 320, 4), f"frame as a numpy array of shape {array.shape}")
lit = np.mean(np.any(array[:, :, :3] != 0, axis=2))
check(lit > 0.05, f"the frame shows the data ({lit:.1%} of pixels lit)")

# Newer cameras supersede queued ones: 12 at once, only the newest must come.
ids = []
for i in range(12):
    angle = i * 0.05
    eye_i = centre + (hi - lo) * np.array([0.9 * np.cos(angle), -0.9 * np.sin(angle) - 0.9, 0.6])
    ids.append(client.request_frame(client.camera(tuple(eye_i), tuple(centre)), "jpeg"))
outcome = {}
deadline = time.monotonic() + 120
try:
    while len(outcome) < len(ids) and time.monotonic() < deadline:
        header, pixels = client.receive_frame(timeout=120)
        if header.interim:
            continue  # the render cache's; the final frame follows
        outcome[header.request_id] = (header.status, len(pixels))
except Exception as error:  # a timeout: say what is missing, then the checks fail
    missing = [i for i in ids if i not in outcome]
    print(f"supersede: {error}; nothing for requests {missing}; got {outcome}; "
          f"{client.stats().frames_dropped} frames dropped")
superseded = sum(1 for status, _ in outcome.values() if status == pb.FRAME_STATUS_SUPERSEDED)
check(len(outcome) == len(ids), f"every request got a frame or a notice ({len(outcome)})")
check(outcome.get(ids[-1], (0, 0))[0] == pb.FRAME_STATUS_OK and outcome[ids[-1]][1] > 0,
      "the newest camera's frame came, as JPEG")
check(superseded >= 1, f"{superseded} queued camera(s) superseded by newer ones")
check(all(n == 0 for status, n in outcome.values() if status == pb.FRAME_STATUS_SUPERSEDED),
      "superseded notices carry no pixels")
client.close()

# A reader slower than its frames: with its stream full (the job's
# --stream-hwm 4, one frame held here), a render request's final frame or
# superseded notice waits at the service for room instead of being lost.
slow = PointillistClient(endpoint, name="slow-reader", stream_receive_hwm=1)
slow.call(pb.Request(set_options=pb.SetOptionsRequest(
    format=pb.FrameFormat(width=640, height=360))))
ids = []
for i in range(12):
    angle = 0.3 + i * 0.05
    eye_i = centre + (hi - lo) * np.array([0.9 * np.cos(angle), -0.9 * np.sin(angle) - 0.9, 0.6])
    ids.append(slow.request_frame(slow.camera(tuple(eye_i), tuple(centre)), "raw"))
    time.sleep(0.15)  # drawn before the next comes: a frame each, not superseded
time.sleep(2)  # still not reading: the stream is full
outcome = {}
deadline = time.monotonic() + 60
try:
    while len(outcome) < len(ids) and time.monotonic() < deadline:
        header, pixels = slow.receive_frame(timeout=30)
        if not header.interim:
            outcome[header.request_id] = header.status
except Exception as error:  # a timeout: the check below says what is missing
    print(f"slow reader: {error}")
print(f"slow reader: statuses {sorted(outcome.values())}, "
      f"{slow.stats().frames_dropped} frames dropped")
check(len(outcome) == len(ids),
      f"a slow reader got a frame or a notice for every request ({len(outcome)} of {len(ids)})")
check(outcome.get(ids[-1]) == pb.FRAME_STATUS_OK, "the slow reader's newest camera's frame came")
slow.close()
if failures:
    print(f"{len(failures)} check(s) failed")
    sys.exit(1)
print("every bad request was refused and the service kept serving")
