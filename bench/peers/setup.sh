#!/usr/bin/env bash
# The peer benchmark's own set-up (bench/peers/cycles.py): Debian's Blender
# (3.4.1 on Debian 12), whose Cycles renders the same scene. The test
# command never runs this.
set -euo pipefail
if ! command -v blender >/dev/null; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends blender >/dev/null
fi
blender -b --factory-startup -noaudio --python-expr "import bpy; print('Blender', bpy.app.version_string)" 2>/dev/null | grep '^Blender [0-9]'
