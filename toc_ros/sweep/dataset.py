# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
The results: a Parquet dataset OUT/results/part-NNNNNN.parquet, one file per finished task.

Each file is written to a hidden temporary name and renamed, so a crash leaves whole files
only; readers (pyarrow, pandas, DuckDB, Spark) take the directory as one dataset.
OUT/sweep.json records the columns and the spec; --resume refuses a dataset whose columns
differ from the spec's.
"""

import datetime
import json
import os
import re
import socket

import pyarrow as pa
import pyarrow.parquet as pq

RESULT_COLUMNS = (
    ('status', pa.string()), ('final_time', pa.float64()), ('iterations', pa.int64()),
    ('wall_time_s', pa.float64()), ('max_control_excess', pa.float64()),
    ('terminal_error', pa.float64()), ('min_clearance', pa.float64()), ('worker', pa.string()),
    ('message', pa.string()), ('args', pa.string()))
# Arm sweeps only: the goal joint positions the solver got (from IK for a tip target) and the
# last state's positions of the returned trajectory (null when there is none).
ARM_COLUMNS = (('goal_q', pa.list_(pa.float64())), ('final_q', pa.list_(pa.float64())))
TYPES = {'float64': pa.float64(), 'int64': pa.int64(), 'string': pa.string()}
_PART = re.compile(r'^part-(\d+)\.parquet$')


class DatasetError(RuntimeError):
    """The output directory cannot be used as asked."""


def schema_for(sweep, arm=False):
    """Arrow schema: case_id, one column per varied name, the result columns (arm: ARM_COLUMNS)."""
    results = RESULT_COLUMNS + (ARM_COLUMNS if arm else ())
    clash = [n for n in sweep.names if n in dict(results) or n == 'case_id']
    if clash:
        raise DatasetError(f'varied name(s) {", ".join(clash)} clash with result columns')
    return pa.schema([('case_id', pa.string())]
                     + [(n, TYPES[sweep.column_types[n]]) for n in sweep.names]
                     + list(results))


def _columns(schema):
    return [[f.name, str(f.type)] for f in schema]


class Dataset:
    """OUT/results as a Parquet dataset, written one file per call of write()."""

    def __init__(self, out_dir, schema):
        self.out = os.path.abspath(out_dir)
        self.dir = os.path.join(self.out, 'results')
        self.schema = schema
        self.meta_path = os.path.join(self.out, 'sweep.json')
        self.lock_path = os.path.join(self.out, '.lock')
        self.locked = False
        self.next_part = 1

    def files(self):
        """Finished part files, in write order."""
        if not os.path.isdir(self.dir):
            return []
        names = sorted(n for n in os.listdir(self.dir) if _PART.match(n))
        return [os.path.join(self.dir, n) for n in names]

    def prepare(self, resume, spec_text=''):
        """Create OUT, or check it for --resume; return the case ids already there."""
        files = self.files()
        if files and not resume:
            raise DatasetError(f'{self.out} already holds {len(files)} result file(s): pass '
                               '--resume to add the missing cases, or choose another --out')
        if os.path.isfile(self.meta_path) and resume:
            try:
                with open(self.meta_path) as stream:
                    columns = json.load(stream)['columns']
            except (OSError, ValueError, KeyError) as exc:
                raise DatasetError(f'cannot read {self.meta_path}: {exc}')
            if columns != _columns(self.schema):
                raise DatasetError(
                    f'{self.out} holds a sweep with other columns '
                    f'({", ".join(c[0] for c in columns)}) than this spec '
                    f'({", ".join(f.name for f in self.schema)}): use another --out')
        try:
            os.makedirs(self.dir, exist_ok=True)
            self._lock()
            for name in os.listdir(self.dir):     # leftovers of a crash while writing
                if name.startswith('.part-'):
                    os.remove(os.path.join(self.dir, name))
            if not os.path.isfile(self.meta_path):
                self._write_json(self.meta_path, {
                    'columns': _columns(self.schema), 'spec': spec_text,
                    'created': datetime.datetime.now(datetime.timezone.utc).isoformat()})
        except OSError as exc:
            raise DatasetError(f'cannot write to {self.out}: {exc}')
        indices = [int(_PART.match(os.path.basename(f)).group(1)) for f in files]
        self.next_part = max(indices, default=0) + 1
        return self.case_ids()

    def _lock(self):
        """Take OUT/.lock (pid@host); a lock of a process that is gone is taken over."""
        me = f'{os.getpid()}@{socket.gethostname()}'
        for _ in range(2):
            try:
                fd = os.open(self.lock_path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                try:
                    with open(self.lock_path) as stream:
                        owner = stream.read().strip()
                except OSError:
                    owner = ''
                pid, _, host = owner.partition('@')
                if host == socket.gethostname() and pid.isdigit() and not _alive(int(pid)):
                    os.remove(self.lock_path)        # stale: its process is gone
                    continue
                raise DatasetError(f'{self.out} is in use by another toc-sweep ({owner or "?"}; '
                                   f'remove {self.lock_path} if that is wrong)')
            with os.fdopen(fd, 'w') as stream:
                stream.write(me + '\n')
            self.locked = True
            return
        raise DatasetError(f'cannot take {self.lock_path}')

    def close(self):
        """Release OUT/.lock."""
        if self.locked:
            self.locked = False
            try:
                os.remove(self.lock_path)
            except FileNotFoundError:
                pass  # already gone (removed by hand): nothing left to release

    def case_ids(self):
        """Case ids in the dataset."""
        ids = set()
        for path in self.files():
            ids.update(pq.read_table(path, columns=['case_id']).column(0).to_pylist())
        return ids

    def write(self, rows):
        """Write rows (dicts) as the next part file; return its path."""
        table = pa.Table.from_pylist(rows, schema=self.schema)
        name = f'part-{self.next_part:06d}.parquet'
        self.next_part += 1
        tmp = os.path.join(self.dir, '.' + name + '.tmp')
        pq.write_table(table, tmp)
        path = os.path.join(self.dir, name)
        os.replace(tmp, path)
        return path

    def read(self, case_ids=None):
        """All rows as one Table (first copy of each case; only case_ids if given)."""
        tables = [pq.read_table(path, schema=self.schema) for path in self.files()]
        if not tables:
            return self.schema.empty_table()
        table = pa.concat_tables(tables)
        seen = set()
        keep = []
        for i, cid in enumerate(table.column('case_id').to_pylist()):
            if cid not in seen and (case_ids is None or cid in case_ids):
                seen.add(cid)
                keep.append(i)
        return table.take(keep)

    @staticmethod
    def _write_json(path, doc):
        tmp = path + '.tmp'
        with open(tmp, 'w') as stream:
            json.dump(doc, stream, indent=1)
            stream.write('\n')
        os.replace(tmp, path)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
