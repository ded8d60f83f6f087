"""Running training runs, below the campaign store, the loop and the audit: a run described by one
:class:`~autoresearch.execution.spec.RunSpec`, executed on this machine or on Ray through one
interface (executors), its processes tracked and stopped (processes, tracking), its output read
under the family contract (protocol), its outcome a :class:`~autoresearch.execution.result.RunResult`."""
