"""``kmpipe run``: every stage a recipe needs, as a graph of cached tasks, in one process, a process pool or Dask.

Tasks (``id``: what it writes under the output folder):

- ``material:P`` (products with a source): measure the sample on the CS-2000 at the recipe's port (live; recorded
  byte for byte into ``products/P/session.jsonl``; a session cut short is resumed by the next run) or replay a
  recorded session, into ``products/P/session/``, and fit it; or fit the manifest; or copy the material file; writes
  ``products/P/material.json``. A live measurement is keyed by its plan and port, so it is measured once;
- ``validate:P`` (materials fitted from measurements): ``reports/P/report.html`` and ``validation.json``;
- ``plan:P`` (products with layers): the render plan of the product's scene (mode, optical tables, shadow maps, what
  was dropped and why; :mod:`kmpipe.stages.plan_file`) into ``frames/P/plan.json``, keyed by what its renders read;
- ``render:P:A-B`` (products with layers): frames A..B of the turntable into ``frames/P/``, a few frames a task so
  that several workers share a product, rendered as the product's plan file says (no task plans again); waits for
  the plan, the materials its layers use and their validation: a material that failed validation is not rendered
  unless ``keep_going`` (then its frames say so in their header);
- ``video:P`` (products with a turntable of 2 or more frames): ``frames/P/turntable.mp4`` and ``turntable.webp``
  from its frames (:mod:`kmpipe.stages.video`), keyed by its render tasks and the video settings;
- ``reports``: ``reports/index.html`` and ``summary.json`` over every validated product;
- ``sheet``: the contact sheet, a row per rendered product and a column per angle.

Caching. Every task has a key, the SHA-256 of what determines its result: its kind and settings, the content of the
input files it reads, the keys of the tasks it depends on, and kmpipe's version. When a task finishes, a record of its
key and outputs goes to ``.kmpipe/tasks/`` (written atomically, as soon as that task finishes, whichever executor ran
it). A task whose record holds its current key and whose outputs all exist is not run again: a second run does
nothing, and changing one product's data changes the keys of exactly that product's tasks (and of the line's sheet
and index). Every file is written under a temporary name and renamed, so a run killed at any moment leaves finished
files or none, and the next run resumes, first deleting the hidden temporary files a killed write left (kmpipe's own
temporary names only, see :data:`kmpipe.run.folder.TEMPORARY`).

Safety. Every path the run writes or deletes is resolved and must lie inside the output folder: at planning (a
symlink under the output folder leading out of it is refused, naming the path) and again in the task, right before it
writes (a symlink made meanwhile is refused too); a session folder is deleted without following symlinks. The outputs
of one run never collide: a recipe whose ``[outputs]`` make two tasks write the same file, or put the frames, reports,
products and records folders inside one another, is refused at planning, naming the field. One run at a time writes
an output folder: :func:`kmpipe.run.execute.execute` holds ``.kmpipe/lock`` (:func:`kmpipe.run.folder.locked`,
an ``flock`` released by the kernel when the process ends, however it ends); another run is refused naming the
holder (pid, host, since when), or waits for it. Planning (``--dry-run``) takes no lock and writes nothing.

Executors: ``local`` runs tasks in this process (``workers`` = 1) or in a pool of spawned processes; ``dask`` sends
them to a Dask distributed scheduler (``scheduler`` address) or to a local Dask cluster of ``workers`` processes. Task
functions are plain module functions of file paths and settings; the output folder must be visible to every worker
(a shared file system). Results are identical whichever executor ran them: the same code renders each frame. At most
a few tasks per worker are handed out at a time, so that the work of scheduling grows linearly with the line.

Modules: :mod:`~kmpipe.run.planning` (the graph, keys, what is cached, where tasks write), :mod:`~kmpipe.run.tasks`
(what each task does), :mod:`~kmpipe.run.executors` (where tasks run), :mod:`~kmpipe.run.execute` (running a plan),
:mod:`~kmpipe.run.folder` (the output folder's layout, lock and clean-up).
"""
