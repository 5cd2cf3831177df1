"""`python3 -m nanovdb_mitsuba`: prints the directory that holds plugins/, for
Mitsuba's command line: mitsuba -a "$(python3 -m nanovdb_mitsuba)" scene.xml"""
from . import plugin_root

print(plugin_root())
