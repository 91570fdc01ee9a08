#!/usr/bin/env python3
"""Prints one closing line 'N passed, N failed, N skipped' over the JUnit XML
files that catkin's run_tests wrote, and exits non-zero on any failure or
when no test ran at all."""
import glob
import os
import sys
import xml.etree.ElementTree as ET

root = sys.argv[1]
passed = failed = skipped = 0
for path in glob.glob(os.path.join(root, "**", "*.xml"), recursive=True):
    try:
        tree = ET.parse(path).getroot()
    except ET.ParseError:
        failed += 1
        print(f"unreadable result file: {path}")
        continue
    for case in tree.iter("testcase"):
        if case.find("failure") is not None or case.find("error") is not None:
            failed += 1
            print(f"FAILED: {os.path.basename(path)} {case.get('classname')}.{case.get('name')}")
        elif case.find("skipped") is not None:
            skipped += 1
        else:
            passed += 1
print(f"{passed} passed, {failed} failed, {skipped} skipped")
sys.exit(1 if failed or passed == 0 else 0)
