#!/usr/bin/env python3
"""Generate Python message classes with genpy, without catkin.

For every project package (a top-level folder holding a package.xml) its
``msg/*.msg`` and ``srv/*.srv`` become ``<pkg>/msg/_X.py`` and ``<pkg>/srv/_X.py``
next to the definitions, so that ``import <pkg>.msg`` works both from the venv
and from Debian's ROS tools (which only need the repository on PYTHONPATH).
The output is never committed (see .gitignore) and is regenerated only when a
definition is newer than its module.

Usage: gen_msgs.py [--force] REPO_ROOT
"""
import glob
import os
import sys

import genpy.generate_initpy
import genpy.generator


def project_packages(root):
    return sorted(os.path.basename(os.path.dirname(p))
                  for p in glob.glob(os.path.join(root, '*', 'package.xml')))


def search_path(root):
    """Message search path: every project package plus Debian's ros-*-msgs."""
    path = {}
    for d in sorted(glob.glob('/usr/share/*/msg')):
        path.setdefault(os.path.basename(os.path.dirname(d)), []).append(d)
    for pkg in project_packages(root):
        path.setdefault(pkg, []).insert(0, os.path.join(root, pkg, 'msg'))
    return path


def stale(defs, out_dir):
    for d in defs:
        mod = os.path.join(out_dir, '_' + os.path.splitext(os.path.basename(d))[0] + '.py')
        if not os.path.exists(mod) or os.path.getmtime(mod) < os.path.getmtime(d):
            return True
    return not os.path.exists(os.path.join(out_dir, '__init__.py'))


def main(argv):
    force = '--force' in argv
    args = [a for a in argv if a != '--force']
    root = os.path.abspath(args[0] if args else os.path.dirname(os.path.dirname(__file__)))
    search = search_path(root)
    generated = 0
    for pkg in project_packages(root):
        for kind, gen_cls in (('msg', genpy.generator.MsgGenerator), ('srv', genpy.generator.SrvGenerator)):
            out_dir = os.path.join(root, pkg, kind)
            defs = sorted(glob.glob(os.path.join(out_dir, '*.' + kind)))
            if not defs or not (force or stale(defs, out_dir)):
                continue
            rc = gen_cls().generate_messages(pkg, defs, out_dir, search)
            if rc:
                print('error: genpy failed for %s/%s (rc %s)' % (pkg, kind, rc), file=sys.stderr)
                return rc
            genpy.generate_initpy.write_modules(out_dir)
            generated += len(defs)
    print('messages: %d definitions generated' % generated if generated else 'messages: up to date')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
