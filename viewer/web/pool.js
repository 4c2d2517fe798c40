// A pool of decoding workers, each given one job at a time; waiting jobs go out by
// priority (the drawn pair's visible tiles before the rest), not in arrival order.
export class Workers {
  constructor(n) {
    this.pool = Array.from({ length: n }, () => new Worker(new URL("./worker.js", import.meta.url), { type: "module" }));
    this.idle = [...this.pool];
    this.jobs = [];
    this.id = 0;
    this.maxMs = 0;
    this.totalMs = 0;
    this.count = 0;
    for (const w of this.pool) {
      w.onmessage = (ev) => {
        this.maxMs = Math.max(this.maxMs, ev.data.ms ?? 0);
        this.totalMs += ev.data.ms ?? 0;
        this.count++;
        const cb = w.job.resolve;
        w.job = null;
        this.idle.push(w);
        this.next();
        cb(ev.data);
      };
    }
  }
  run(msg, pri = 0) {
    return new Promise((resolve) => {
      this.jobs.push({ msg: { ...msg, id: ++this.id }, resolve, pri, order: this.id });
      this.next();
    });
  }
  next() {
    while (this.idle.length && this.jobs.length) {
      let best = 0;
      for (let i = 1; i < this.jobs.length; i++) {
        const a = this.jobs[i];
        const b = this.jobs[best];
        if (a.pri < b.pri || (a.pri === b.pri && a.order < b.order)) best = i;
      }
      const job = this.jobs.splice(best, 1)[0];
      const w = this.idle.pop();
      w.job = job;
      w.postMessage(job.msg);
    }
  }
}
