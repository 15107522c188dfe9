"""docs/testing.md's example of a user's own test runs as written, as a pytest run of its own."""
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_the_user_test_in_the_docs_passes_in_a_pytest_run_of_its_own(tmp_path):
    with open(os.path.join(ROOT, 'docs', 'testing.md'), encoding='utf-8') as f:
        example = re.search(r'```python\n(.*?)```', f.read(), re.S).group(1)
    assert 'pytest_plugins' not in example       # the installed plugin comes by its entry point
    (tmp_path / 'test_my_robot.py').write_text(example)
    # outside the repository: none of its conftest files, only what the file itself names
    out = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', 'test_my_robot.py'],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert '1 passed' in out.stdout
