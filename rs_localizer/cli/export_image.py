"""``rs-localizer export-image``: images of a bag as image files: one message as a PNG (e.g. a
``replay --debug-outputs`` debug image for a document), or every image of a topic into a
folder (e.g. a video for ``map-markers`` or ``map-features --images``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import args as A

__all__ = ["STAMPS_FILE", "register", "run"]

#: ``--all``: each image file's header stamp (ns), one ``file,stamp_ns`` row per image
STAMPS_FILE = "stamps.csv"

HELP = "write an image of a bag (or all of them: --all) as PNG/JPEG files"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``export-image`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    e = sub.add_parser(
        "export-image",
        help=HELP,
        description="Write one sensor_msgs/Image or CompressedImage message of a bag as an "
        "image file, or with --all every image of the topic into the folder OUT "
        "(000000.png, 000001.png, ... in bag order, and stamps.csv: each file's header stamp "
        "in ns).",
        formatter_class=A.HelpFormatter,
    )
    e.add_argument("bag", help="bag directory (or its .mcap / .db3 file)")
    e.add_argument("out", help="image file to write (.png, .jpg); with --all: a folder")
    e.add_argument(
        "--topic",
        default=None,
        help="image topic (default: the bag's only image topic, e.g. the camera's or a "
        "replay's /rs_localizer/debug_image)",
    )
    e.add_argument(
        "--index", type=A.nonneg_int, default=0, help="message number on the topic (0 = first)"
    )
    e.add_argument(
        "--all", action="store_true", help="every image of the topic into the folder OUT"
    )
    e.add_argument(
        "--format",
        choices=["png", "jpg"],
        default="png",
        help="file format of --all (png: lossless; jpg: quality 95, smaller)",
    )
    e.add_argument(
        "--colors",
        type=A.nonneg_int,
        default=0,
        help="PNG with a palette of this many colours (smaller file; 0: full colour)",
    )
    e.add_argument("--overwrite", action="store_true", help="--all: write into an existing OUT")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=run)
    return e


def _image_topic(bag: Path, topic: str | None) -> str:
    from ..ros.bags.bag_io import COMPRESSED_IMAGE, IMAGE, bag_topics

    topics = bag_topics(bag)
    images = sorted(t for t, mt in topics.items() if mt in (IMAGE, COMPRESSED_IMAGE))
    if topic is None:
        if len(images) != 1:
            raise A.CliError(
                f"{bag}: {'no image topic' if not images else 'image topics ' + ', '.join(images)}"
                + (": choose one with --topic" if images else "")
            )
        return images[0]
    if topic not in images:
        raise A.CliError(
            f"{bag}: no sensor_msgs/Image topic {topic!r} (image topics: "
            f"{', '.join(images) or 'none'})"
        )
    return topic


def _decode(ts, raw: bytes, msgtype: str):
    from ..ros.conversions import stamp_to_ns
    from ..ros.image_codec import decode_image
    from ..viz.debug_image import to_bgr

    msg = ts.deserialize_cdr(raw, msgtype)
    img, enc = decode_image(msg, min_side=0)
    stamp_ns = stamp_to_ns(msg.header.stamp)
    return img, enc, to_bgr(img, enc), stamp_ns


def run(args: argparse.Namespace) -> int:
    """Write the image(s); returns 0. Raises CliError for a bag without the image topic, an
    index beyond the topic's messages, or an output that cannot be written (checked first)."""
    import cv2

    from ..ros.bags.bag_io import iter_messages, typestore

    bag = A.bag_dir(args.bag, require_messages=True)
    out = Path(args.out)
    if args.all:
        A.output_dir(out, True, "image folder")
        if out.exists() and any(out.iterdir()) and not args.overwrite:
            raise A.CliError(f"{out}: exists and is not empty (use --overwrite to write into it)")
    else:
        A.output_file(out, True, "image file")
        if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
            raise A.CliError(f"{out}: expected a .png or .jpg name")
    topic = _image_topic(bag, args.topic)
    ts = typestore()
    if args.all:
        return _export_all(bag, topic, out, args, ts)
    count = 0
    for k, (_, mt, _, raw) in enumerate(iter_messages(bag, {topic})):
        count += 1
        if k != args.index:
            continue
        img, enc, bgr, _ = _decode(ts, raw, mt)
        out.parent.mkdir(parents=True, exist_ok=True)
        if args.colors:
            import numpy as np
            from PIL import Image  # (Pillow comes with matplotlib)

            Image.fromarray(np.ascontiguousarray(bgr[:, :, ::-1])).quantize(
                colors=args.colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
            ).save(str(out), optimize=True)
        elif not cv2.imwrite(str(out), bgr, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            raise A.CliError(f"{out}: cannot write the image (use a .png or .jpg name)")
        print(
            f"wrote {out}: message {k} of {topic} ({img.shape[1]}x{img.shape[0]}, "
            f"{enc}, {out.stat().st_size / 1024:.0f} KiB)"
        )
        return 0
    raise A.CliError(f"{topic} has {count} messages; --index {args.index} is out of range")


def _export_all(bag: Path, topic: str, out: Path, args: argparse.Namespace, ts) -> int:
    import cv2
    from rosbags.rosbag2 import Reader
    from tqdm import tqdm

    from ..ros.bags.bag_io import iter_messages

    with Reader(bag) as r:
        total = sum(c.msgcount for c in r.connections if c.topic == topic)
    out.mkdir(parents=True, exist_ok=True)
    params = (
        [cv2.IMWRITE_JPEG_QUALITY, 95] if args.format == "jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 1]
    )
    n, size, rows = 0, None, ["file,stamp_ns"]
    msgs = tqdm(
        iter_messages(bag, {topic}), total=total, desc="images", unit="img", disable=args.quiet
    )
    for _, mt, _, raw in msgs:
        img, _, bgr, stamp_ns = _decode(ts, raw, mt)
        path = out / f"{n:06d}.{args.format}"
        if not cv2.imwrite(str(path), bgr, params):
            raise A.CliError(f"{path}: cannot write the image")
        rows.append(f"{path.name},{stamp_ns}")
        n, size = n + 1, img.shape
    (out / STAMPS_FILE).write_text("\n".join(rows) + "\n")
    print(
        f"wrote {n} images of {topic} into {out}"
        + (f" ({size[1]}x{size[0]}, {args.format})" if size else "")
        + f", their header stamps in {out / STAMPS_FILE}"
    )
    return 0
