"""Make Debian's ROS 1 Python packages importable from a venv (run with the system python3 that has them).

Links the top-level modules that rospy, rostopic and the message packages load from Debian's dist-packages
(and every installed *_msgs package) into VENV/ros1, and appends that folder to the venv's path with a .pth
file: the venv's own packages still come first, and nothing else of the system's is seen. Needs the venv's
Python to have the same major.minor version (Debian's compiled modules, such as yaml's, are built for it).
Usage: /usr/bin/python3 scripts/link_ros1.py .venv
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path("/usr/lib/python3/dist-packages")
SKIP = {"_distutils_hack", "setuptools", "pkg_resources", "pip"}


def main(venv: Path) -> int:
    import rosgraph  # noqa: F401  (the modules a node and rostopic load)
    import rosmaster  # noqa: F401
    import rospy  # noqa: F401
    import rostopic  # noqa: F401
    import roslib.message  # noqa: F401
    import sensor_msgs.msg  # noqa: F401
    import std_msgs.msg  # noqa: F401

    python = venv / "bin" / "python"
    info = subprocess.run([str(python), "-c", "import sys, sysconfig; print('%d.%d' % sys.version_info[:2]); "
                           "print(sysconfig.get_paths()['purelib'])"], capture_output=True, text=True, check=True)
    version, purelib = info.stdout.split("\n")[:2]
    mine = "%d.%d" % sys.version_info[:2]
    if version != mine:
        print(f"setup: ROS 1 is for Python {mine}, {venv} is Python {version}: not linked; the ROS test will say so")
        return 0
    names = {n.split(".")[0] for n, m in list(sys.modules.items())
             if str(getattr(m, "__file__", None) or "").startswith(str(ROOT) + "/")}
    names |= {p.name for p in ROOT.iterdir() if p.is_dir() and p.name.endswith("_msgs")}
    folder = venv / "ros1"
    folder.mkdir(exist_ok=True)
    for name in sorted(names - SKIP):
        source = ROOT / name if (ROOT / name).exists() else ROOT / f"{name}.py"
        link = folder / source.name
        if not link.is_symlink() and source.exists():
            link.symlink_to(source)
    (Path(purelib) / "debian-ros1.pth").write_text(str(folder.resolve()) + "\n")
    print(f"setup: ROS 1 (Debian) linked into {venv}: {len(list(folder.iterdir()))} modules")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
