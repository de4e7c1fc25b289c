// The live hub (WebSocket on the server's ws_port): poses, tiles written, changes found and the
// run finished, for the runs on screen; reconnects with a growing pause.
export class Live {
  constructor(onMessage, onState) {
    this.onMessage = onMessage;
    this.onState = onState;
    this.runs = [];
    this.delay = 500;
  }

  connect(info) {
    this.url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.hostname}:${info.ws_port}${info.ws_path}`;
    this.open();
  }

  open() {
    this.socket = new WebSocket(this.url);
    this.socket.onopen = () => {
      this.delay = 500;
      this.onState('connected');
      this.sendSubscription();
    };
    this.socket.onmessage = (event) => {
      let message;
      try {
        message = JSON.parse(event.data);
      } catch {
        return;
      }
      this.onMessage(message);
    };
    this.socket.onclose = () => {
      this.onState('disconnected');
      setTimeout(() => this.open(), this.delay);
      this.delay = Math.min(10_000, this.delay * 2);
    };
    this.socket.onerror = () => {}; // onclose follows and retries
  }

  /** The runs on screen: their poses, tiles, changes and run messages, no other run's. */
  subscribe(runs) {
    const gone = this.runs.filter((r) => !runs.includes(r));
    this.runs = [...runs];
    if (this.socket?.readyState === WebSocket.OPEN && gone.length) {
      this.socket.send(JSON.stringify({ unsubscribe: gone }));
    }
    this.sendSubscription();
  }

  sendSubscription() {
    if (this.socket?.readyState === WebSocket.OPEN && this.runs.length) {
      this.socket.send(JSON.stringify({ subscribe: this.runs }));
    }
  }
}
