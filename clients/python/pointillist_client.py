#!/usr/bin/python3
"""A Python client of the Pointillist rendering service (deploy/run.sh --serve).

Uses Debian's python3-zmq, python3-protobuf and python3-numpy. The protobuf
module service_v1_pb2 is generated at build time into build/python; set
POINTILLIST_PYTHON to that folder when the build lives elsewhere.

    client = PointillistClient("tcp://127.0.0.1:5570")
    info = client.info()
    rgba = client.render_array(eye=(x, y, z), target=(x, y, z))   # numpy (H, W, 4), top row first
    client.render_png("frame.png", eye=..., target=..., width=640, height=360)

Command line: pointillist_client.py [--connect EP] info | stats | shutdown
              pointillist_client.py render --camera ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fov]] -o frame.png
"""
import argparse
import itertools
import os
import sys
import time

import numpy as np
import zmq

_here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.environ.get("POINTILLIST_PYTHON",
                                  os.path.join(_here, "..", "..", "build", "python")))
import service_v1_pb2 as pb  # noqa: E402  (generated at build time)

ENCODINGS = {"raw": pb.ENCODING_RAW_RGBA, "png": pb.ENCODING_PNG, "jpeg": pb.ENCODING_JPEG}


class ServiceError(Exception):
    """An error reply: .code is a pb.ErrorCode value, .name its name."""

    def __init__(self, error):
        super().__init__(f"{pb.ErrorCode.Name(error.code)}: {error.message}")
        self.code = error.code
        self.name = pb.ErrorCode.Name(error.code)


def read_curve_key(path):
    """The one Z85 key in a key file (pointillist-client keygen writes them)."""
    keys = []
    with open(path, encoding="ascii") as lines:
        for number, line in enumerate(lines, 1):
            line = line.strip()
            # Z85 has '#' among its characters: only a line starting with it is a comment.
            if not line or line.startswith("#"):
                continue
            if len(line) != 40:
                raise ValueError(f"{path}:{number}: not a Z85 CURVE key (40 characters)")
            keys.append(line.encode("ascii"))
    if len(keys) != 1:
        raise ValueError(f"{path}: holds {len(keys)} keys, expected one")
    return keys[0]


class PointillistClient:
    def __init__(self, endpoint="tcp://127.0.0.1:5570", name="pointillist-client.py",
                 timeout=30.0, curve_server_key=None, curve_secret_key=None,
                 stream_receive_hwm=None):
        """curve_server_key and curve_secret_key: key files (the server's public key,
        this client's secret key) for a service started with --curve-secret-key.
        stream_receive_hwm: frames held here unread at most (ZeroMQ's default
        otherwise); the service keeps the rest of a render request's frames
        until there is room, and drops path frames."""
        self.timeout_ms = int(timeout * 1000)
        self._ids = itertools.count(1)
        self._context = zmq.Context()
        self._curve = None
        if (curve_server_key is None) != (curve_secret_key is None):
            raise ValueError("CURVE needs both the server's public key and this client's secret key")
        if curve_server_key is not None:
            secret = read_curve_key(curve_secret_key)
            self._curve = (read_curve_key(curve_server_key), zmq.curve_public(secret), secret)
        self.control = self._socket()
        self.control.connect(endpoint)
        self.client_id = ""
        hello = self.call(pb.Request(hello=pb.Hello(client_name=name))).hello
        self.client_id = hello.client_id
        self.default_format = hello.format
        self.stream = self._socket()
        self.stream.setsockopt(zmq.ROUTING_ID, self.client_id.encode())
        if stream_receive_hwm is not None:
            self.stream.setsockopt(zmq.RCVHWM, stream_receive_hwm)
        self.stream.connect(self._reachable(hello.stream_endpoint, endpoint))
        attach = pb.Request(version=pb.SERVICE_VERSION_CURRENT, client_id=self.client_id,
                            request_id=next(self._ids), attach=pb.AttachRequest())
        self.stream.send(attach.SerializeToString())
        while True:
            tag, body, _ = self._receive(self.stream, "attach")
            if tag == b"R":
                reply = pb.Reply.FromString(body)
                if reply.HasField("error"):
                    raise ServiceError(reply.error)
                break

    def _socket(self):
        socket = self._context.socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        if self._curve is not None:
            server, public, secret = self._curve
            socket.curve_serverkey = server
            socket.curve_publickey = public
            socket.curve_secretkey = secret
        return socket

    @staticmethod
    def _reachable(advertised, control):
        # A wildcard bind is reached at the host the control socket used.
        for wildcard in ("tcp://0.0.0.0:", "tcp://*:", "tcp://[::]:"):
            if advertised.startswith(wildcard) and control.startswith("tcp://"):
                host = control[len("tcp://"):].rsplit(":", 1)[0]
                return f"tcp://{host}:{advertised[len(wildcard):]}"
        return advertised

    def _receive(self, socket, what, timeout_ms=None):
        if not socket.poll(self.timeout_ms if timeout_ms is None else timeout_ms):
            raise TimeoutError(f"no answer to {what}")
        return socket.recv_multipart()

    def send_raw(self, body):
        """Sends bytes as a request and returns the Reply (for tests of bad messages)."""
        self.control.send_multipart([b"", body])
        return pb.Reply.FromString(self._receive(self.control, "request")[-1])

    def call(self, request):
        request.version = pb.SERVICE_VERSION_CURRENT
        request.client_id = self.client_id
        request.request_id = next(self._ids)
        self.control.send_multipart([b"", request.SerializeToString()])
        while True:
            reply = pb.Reply.FromString(self._receive(self.control, "request")[-1])
            if reply.request_id == request.request_id:
                break
        if reply.HasField("error"):
            raise ServiceError(reply.error)
        return reply

    def info(self):
        return self.call(pb.Request(info=pb.InfoRequest())).info

    def stats(self):
        return self.call(pb.Request(stats=pb.StatsRequest())).stats

    def set_options(self, mode="", lod_pixels=0.0, scheduler=""):
        """This client's mode and level of detail, every client's scheduler; returns an OptionsReply."""
        return self.call(pb.Request(set_options=pb.SetOptionsRequest(
            mode=mode, lod_pixels=lod_pixels, scheduler=scheduler))).options

    def shutdown(self, reason="asked by pointillist_client.py"):
        self.call(pb.Request(shutdown=pb.ShutdownRequest(reason=reason)))

    @staticmethod
    def camera(eye, target, up=None, fov=0.0):
        key = pb.CameraKey(eye=pb.Vec3(x=eye[0], y=eye[1], z=eye[2]),
                           target=pb.Vec3(x=target[0], y=target[1], z=target[2]),
                           fov_y_degrees=fov)
        if up is not None:
            key.up.CopyFrom(pb.Vec3(x=up[0], y=up[1], z=up[2]))
        return key

    def request_frame(self, camera, encoding="png", width=0, height=0, jpeg_quality=0):
        """Asks for one frame; returns its request id (frames come on the stream)."""
        fmt = pb.FrameFormat(width=width, height=height, encoding=ENCODINGS[encoding],
                             jpeg_quality=jpeg_quality)
        request = pb.Request(render=pb.RenderRequest(camera=camera, format=fmt))
        self.call(request)
        return request.request_id

    def receive_frame(self, timeout=120.0):
        """The next (FrameHeader, bytes) on the stream."""
        while True:
            tag, body, pixels = self._receive(self.stream, "frame", int(timeout * 1000))
            if tag == b"F":
                return pb.FrameHeader.FromString(body), pixels

    def frame(self, camera, encoding="png", width=0, height=0, timeout=120.0):
        request_id = self.request_frame(camera, encoding, width, height)
        while True:
            header, pixels = self.receive_frame(timeout)
            # Interim frames (the display's render cache) come first; the
            # final one is the answer.
            if header.request_id == request_id and not header.interim:
                if header.status != pb.FRAME_STATUS_OK:
                    raise RuntimeError(f"frame {pb.FrameStatus.Name(header.status)}")
                return header, pixels

    def render_array(self, eye, target, up=None, fov=0.0, width=0, height=0):
        """One frame as a numpy array of shape (height, width, 4), uint8 RGBA, top row first."""
        header, pixels = self.frame(self.camera(eye, target, up, fov), "raw", width, height)
        return np.frombuffer(pixels, dtype=np.uint8).reshape(header.height, header.width, 4)

    def render_png(self, path, eye, target, up=None, fov=0.0, width=0, height=0):
        """One frame written as a PNG file; returns its FrameHeader."""
        header, pixels = self.frame(self.camera(eye, target, up, fov), "png", width, height)
        with open(path + ".part", "wb") as out:
            out.write(pixels)
        os.replace(path + ".part", path)
        return header

    def close(self):
        self.control.close()
        self.stream.close()
        self._context.term()


def _parse_camera(text):
    values = [float(v) for v in text.split(",")]
    if len(values) not in (6, 9, 10):
        raise SystemExit("--camera takes ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fov]]")
    up = values[6:9] if len(values) >= 9 else None
    return values[0:3], values[3:6], up, values[9] if len(values) == 10 else 0.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", default="tcp://127.0.0.1:5570")
    parser.add_argument("--timeout", type=float, default=30.0)
    parser.add_argument("--curve-server-key", help="CURVE: file with the server's public key")
    parser.add_argument("--curve-key", help="CURVE: file with this client's secret key")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("info")
    commands.add_parser("stats")
    commands.add_parser("shutdown")
    render = commands.add_parser("render")
    render.add_argument("--camera", required=True)
    render.add_argument("--size", default="")
    render.add_argument("-o", "--output", required=True, help=".png file, or .npy for the array")
    render.add_argument("--mode", default="", help="points, splats, blended or instanced")
    render.add_argument("--lod-pixels", type=float, default=0.0)
    args = parser.parse_args()
    client = PointillistClient(args.connect, timeout=args.timeout,
                               curve_server_key=args.curve_server_key,
                               curve_secret_key=args.curve_key)
    try:
        if args.command == "render" and (args.mode or args.lod_pixels):
            client.set_options(mode=args.mode, lod_pixels=args.lod_pixels)
        if args.command == "info":
            print(client.info())
        elif args.command == "stats":
            print(client.stats())
        elif args.command == "shutdown":
            client.shutdown()
            print("shutdown requested")
        else:
            eye, target, up, fov = _parse_camera(args.camera)
            width, height = (int(v) for v in args.size.split("x")) if args.size else (0, 0)
            start = time.monotonic()
            if args.output.endswith(".npy"):
                array = client.render_array(eye, target, up, fov, width, height)
                np.save(args.output, array)
                print(f"frame {array.shape} in {1000 * (time.monotonic() - start):.1f} ms")
            else:
                header = client.render_png(args.output, eye, target, up, fov, width, height)
                print(f"frame {header.frame_id}: {header.width}x{header.height}, "
                      f"{header.splats} splats, {1000 * (time.monotonic() - start):.1f} ms")
    finally:
        client.close()


if __name__ == "__main__":
    main()
