"""The GPU as the driver sees it: its name, and the device memory in use
(what nvidia-smi shows). Used by the benchmarks and by the CUDA tests.

NVML through pynvml (package nvidia-ml-py) when importable, in bytes; else
nvidia-smi, in MiB. Both return None without a GPU.
"""
import subprocess


def _nvml(query):
    try:
        import pynvml
    except ImportError:
        return None
    try:
        pynvml.nvmlInit()
    except Exception:
        return None
    try:
        return query(pynvml, pynvml.nvmlDeviceGetHandleByIndex(0))
    except Exception:
        return None
    finally:
        pynvml.nvmlShutdown()


def _smi(field):
    try:
        r = subprocess.run(["nvidia-smi", f"--query-gpu={field}", "--format=csv,noheader,nounits",
                            "-i", "0"], capture_output=True, text=True, timeout=60)
    except Exception:
        return None
    return r.stdout.strip() if r.returncode == 0 and r.stdout.strip() else None


def used_bytes():
    """Device memory in use on GPU 0, in bytes (None without a GPU)."""
    v = _nvml(lambda nv, h: int(nv.nvmlDeviceGetMemoryInfo(h).used))
    if v is not None:
        return v
    s = _smi("memory.used")
    return int(s.split()[0]) * 2**20 if s else None


def device_name():
    """'NVIDIA H100 80GB HBM3, 81559 MiB, driver 580.159.04' (None without a GPU)."""
    s = _smi("name,memory.total,driver_version")
    if not s:
        return None
    name, total, driver = [x.strip() for x in s.split(",")]
    return f"{name}, {total} MiB, driver {driver}"
