#!/usr/bin/env python3
"""Prints one closing line 'N passed, N failed, N skipped' over the JUnit XML
files that catkin's run_tests wrote, and exits non-zero on any failure or
when no test ran at all. Each failed test gets one line with the last line of
its failure message (the assertion and its message), so that a log cut to its tail (CI) still
says why."""
import glob
import os
import sys
import xml.etree.ElementTree as ET

root = sys.argv[1]
passed = failed = skipped = 0


def reason(case):
    """The failure's last meaningful line (a traceback ends with the assertion)."""
    node = case.find("failure")
    if node is None:
        node = case.find("error")
    text = (node.text or "") + "\n" + (node.get("message") or "")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("]]")]
    # Python: the AssertionError line and what follows it (the message with
    # the figures), not the source line of the assert above it.
    for i, ln in enumerate(lines):
        if ln.startswith("AssertionError"):
            last = " ".join(lines[i:])
            break
    else:
        keep = [ln for ln in lines if "Error" in ln or "assert" in ln.lower() or "Failure" in ln]
        last = (keep or lines or ["(no message)"])[-1]
    return last if len(last) <= 600 else last[:597] + "..."


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
            print(f"FAILED: {os.path.basename(path)} {case.get('classname')}.{case.get('name')}: {reason(case)}")
        elif case.find("skipped") is not None:
            skipped += 1
        else:
            passed += 1
print(f"{passed} passed, {failed} failed, {skipped} skipped")
sys.exit(1 if failed or passed == 0 else 0)
