"""A process that writes a journal in a loop and reports each committed step on stdout (for the torn-write
test: it is killed at random points and the journal is checked after). Run: python journal_writer.py PATH."""
import sys

from temoto_core.rr.journal import Journal, JournaledConsumer


def main() -> None:
    journal = Journal(sys.argv[1], run_id='run')
    step = journal.id_floor + 1
    payload = b'x' * 2048          # big enough that a step spans several pages of the file
    while True:
        # one served resource, one consumer, and a hold linked to it, each in its own transaction; every
        # third step releases what the step two before made
        journal.serve(step, 'srv', 'pkg/Req', payload, payload, step, JournaledConsumer(step, '/t', '/n', 'ns', ''))
        journal.hold(step, ('ns', 'rr', 'srv'), step, 'pkg/Req', payload, payload, step)
        if step % 3 == 0:
            journal.release(step - 2)
            journal.unserve(step - 2)
        sys.stdout.write('%d\n' % step)
        sys.stdout.flush()
        step += 1


if __name__ == '__main__':
    main()
