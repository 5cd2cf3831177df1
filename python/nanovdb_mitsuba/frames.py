"""A sequence's frames in nanovdb-render (sequence.py): the input's pattern
('####', '%04d' or a folder of numbered .vdb/.nvdb files), --frames lists,
--shard I/N, and the pattern of the frames' images (output_pattern; a frame
counts as written when its PNG and EXR both are)."""
import os
import re

# '####' or '%04d' / '%d' in a file name
_TOKEN = re.compile(r"#+|%(0?\d*)d")
_FRAME_FILE = re.compile(r"^(.*?)(\d+)(\.n?vdb)$", re.IGNORECASE)


class FrameError(Exception):
    """A frame that cannot be read: reported in one line, never a stop"""


class Pattern:
    """A file name with a frame number in it: prefix, the number padded with
    zeros to `width` digits, suffix. `text` is the pattern as '#'s."""

    def __init__(self, prefix, width, suffix):
        self.prefix, self.width, self.suffix = prefix, max(1, width), suffix

    @property
    def text(self):
        return self.prefix + "#" * self.width + self.suffix

    def path(self, frame):
        return f"{self.prefix}{frame:0{self.width}d}{self.suffix}"

    def found(self):
        """{frame: path} of the files present on disk that match"""
        folder = os.path.dirname(self.prefix) or "."
        base = os.path.basename(self.prefix)
        rx = re.compile("^" + re.escape(base) + r"(\d{%d,})" % self.width +
                        re.escape(self.suffix) + "$")
        frames = {}
        try:
            names = os.listdir(folder)
        except OSError:
            return frames
        for name in names:
            m = rx.match(name)
            if m and (len(m.group(1)) == self.width or not m.group(1).startswith("0")):
                frames[int(m.group(1))] = os.path.join(os.path.dirname(self.prefix), name)
        return frames


def is_sequence(spec):
    """True for 'smoke.####.vdb', 'smoke.%04d.vdb' or a folder"""
    return os.path.isdir(spec) or bool(_TOKEN.search(os.path.basename(spec)))


def parse_pattern(spec):
    """Pattern of a '#' or '%0Nd' file name, or of a folder's numbered
    .vdb/.nvdb files (the largest group sharing a prefix and suffix)"""
    if os.path.isdir(spec):
        groups = {}
        for name in sorted(os.listdir(spec)):
            m = _FRAME_FILE.match(name)
            if m:
                groups.setdefault((m.group(1), m.group(3)), []).append(m.group(2))
        if not groups:
            raise SystemExit(f"nanovdb-render: \"{spec}\": no numbered .vdb or .nvdb files "
                             "(name.0001.vdb ...) in this folder")
        (prefix, suffix), digits = max(groups.items(), key=lambda kv: len(kv[1]))
        return Pattern(os.path.join(spec, prefix), min(len(d) for d in digits), suffix)
    folder, base = os.path.split(spec)
    tokens = list(_TOKEN.finditer(base))
    if len(tokens) != 1:
        raise SystemExit(f"nanovdb-render: \"{spec}\": one frame number field please "
                         "('####' or '%04d'), not several")
    m = tokens[0]
    if m.group(0).startswith("#"):
        width = len(m.group(0))
    else:
        width = int(m.group(1) or "1")
    return Pattern(os.path.join(folder, base[:m.start()]), width, base[m.end():])


def parse_frames(text):
    """'10-120', '10-120:2', '7', '1-5,9,20-30:5' -> sorted frame numbers"""
    frames = set()
    for part in text.split(","):
        m = re.fullmatch(r"\s*(\d+)(?:\s*-\s*(\d+))?(?:\s*:\s*(\d+))?\s*", part)
        if not m or (m.group(3) and int(m.group(3)) < 1):
            raise ValueError(f"--frames: \"{part}\" is not FIRST-LAST[:STEP] or a frame number")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) else first
        if last < first:
            raise ValueError(f"--frames: \"{part}\" ends before it starts")
        frames.update(range(first, last + 1, int(m.group(3) or 1)))
    return sorted(frames)


def parse_shard(text):
    """'I/N' -> (I, N), 0 <= I < N"""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not m or not 0 <= int(m.group(1)) < int(m.group(2)):
        raise ValueError(f"--shard: \"{text}\" is not I/N with 0 <= I < N (e.g. "
                         "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)")
    return int(m.group(1)), int(m.group(2))


def shard_frames(frames, shard):
    """Every N-th of `frames` from the I-th: the shards partition them"""
    i, n = shard
    return frames[i::n]


def _ranges(frames):
    """[1, 2, 3, 7, 9, 10] -> '1-3, 7, 9-10'"""
    out, start, prev = [], None, None
    for f in sorted(frames) + [None]:
        if start is not None and (f is None or f != prev + 1):
            out.append(str(start) if start == prev else f"{start}-{prev}")
            start = None
        if f is not None and start is None:
            start = f
        prev = f
    return ", ".join(out)


def output_pattern(output, pattern):
    """Pattern of the frames' PNGs: -o with '#'s or '%04d', else -o's name
    (default: the input's) with .#### before .png"""
    if output and _TOKEN.search(os.path.basename(output)):
        p = parse_pattern(output)
        return Pattern(p.prefix, max(p.width, 4), os.path.splitext(p.suffix)[0] + ".png")
    if output:
        stem = os.path.splitext(output)[0]
    else:
        stem = os.path.basename(pattern.prefix.rstrip("._-")) or "frame"
    return Pattern(stem + ".", max(pattern.width, 4), ".png")


def written(png):
    """A frame counts as done when both its PNG and EXR are there"""
    return os.path.exists(png) and os.path.exists(os.path.splitext(png)[0] + ".exr")
